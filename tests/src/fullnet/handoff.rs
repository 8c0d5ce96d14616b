//! A second thread that runs one job at a time for the caller, ready within a fraction of a
//! microsecond: it waits for work by spinning, not by sleeping.
//!
//! The full network on two threads hands it the second group of channels for every run of
//! the engine (`Engine::run_until`: one per input change, about 30 a simulated second), and
//! within a run the two threads meet once per window of simulated time, spinning on their
//! own exchange. Handing work to a sleeping thread costs a wake-up: through `rayon::join`
//! on this machine that took the simulation of one minute from 3.4 s to 10.0 s of wall time
//! (idle machine, `fullnet network --minutes 1`; 16,117 batches of an earlier design, about
//! 0.4 ms lost on each). This thread therefore spins between jobs and only parks after
//! [`PARK_AFTER`] without work (the simulation waiting for its caller, or finished), and the
//! caller spins while it waits for the result. It costs a whole core while it spins: worth it
//! on a machine with a core to spare, which is what `--threads 2` asks for.
//!
//! Safe Rust only: the job (its channels included) moves into the thread through a mutex
//! and comes back the same way; the atomic state only says whose turn it is.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

/// How long the thread spins without work before it parks (the next job then waits for a
/// wake-up once). Far longer than the gaps between the engine's runs while a simulation
/// goes on (the caller's input change between two runs takes microseconds), so that a
/// running simulation never waits for a wake-up.
pub const PARK_AFTER: Duration = Duration::from_millis(50);

/// Nothing submitted; the caller may submit.
const IDLE: u8 = 0;
/// A job waits in the slot for the thread.
const SUBMITTED: u8 = 1;
/// The thread has put the finished job back into the slot.
const DONE: u8 = 2;
/// The owner is gone: the thread ends.
const QUIT: u8 = 3;

/// How many spins between two looks at the clock (or at whether the thread still runs).
const SPINS_PER_LOOK: u32 = 1 << 12;

struct Shared<J> {
    state: AtomicU8,
    slot: Mutex<Option<J>>,
}

impl<J> Shared<J> {
    fn put(&self, job: J) {
        // A panic while the lock was held (there is none: the lock only moves the job) would
        // leave the job in the slot as it was; take it as it is.
        *self.slot.lock().unwrap_or_else(PoisonError::into_inner) = Some(job);
    }

    fn take(&self) -> Option<J> {
        self.slot
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take()
    }
}

/// The second thread and the one job it may be working on.
pub struct Handoff<J: Send + 'static> {
    shared: Arc<Shared<J>>,
    thread: Option<JoinHandle<()>>,
}

impl<J: Send + 'static> Handoff<J> {
    /// Starts the thread; it runs `work` on every job submitted and hands the result back.
    pub fn new(mut work: impl FnMut(J) -> J + Send + 'static) -> Self {
        let shared = Arc::new(Shared {
            state: AtomicU8::new(IDLE),
            slot: Mutex::new(None),
        });
        let theirs = Arc::clone(&shared);
        let thread = thread::Builder::new()
            .name("fullnet-second".into())
            .spawn(move || {
                // Since when it has been without work: read off the clock at its first look
                // after a job, not at the end of every job (a clock read costs about as
                // much as a small job's hand-over).
                let mut idle_since: Option<Instant> = None;
                let mut spins = 0u32;
                loop {
                    match theirs.state.load(Ordering::Acquire) {
                        SUBMITTED => {
                            let job = theirs.take().expect("a submitted job is in the slot");
                            theirs.put(work(job));
                            theirs.state.store(DONE, Ordering::Release);
                            idle_since = None;
                        }
                        QUIT => return,
                        _ => {
                            std::hint::spin_loop();
                            spins = spins.wrapping_add(1);
                            if spins % SPINS_PER_LOOK == 0
                                && idle_since.get_or_insert_with(Instant::now).elapsed()
                                    > PARK_AFTER
                            {
                                // `submit` unparks after it has set the state: a job that
                                // came after the load above is not missed (the park returns
                                // at once), and the time-out bounds any other surprise.
                                thread::park_timeout(Duration::from_millis(100));
                            }
                        }
                    }
                }
            })
            .expect("a thread for the full network's second half");
        Handoff {
            shared,
            thread: Some(thread),
        }
    }

    /// Hands `job` to the thread; [`Handoff::wait`] gives it back done. One job at a time.
    pub fn submit(&mut self, job: J) {
        assert_eq!(
            self.shared.state.load(Ordering::Acquire),
            IDLE,
            "one job at a time: the last one was not waited for"
        );
        self.shared.put(job);
        self.shared.state.store(SUBMITTED, Ordering::Release);
        if let Some(thread) = &self.thread {
            // Costs a system call only when the thread is parked.
            thread.thread().unpark();
        }
    }

    /// Whether the thread has stopped (it panicked: it runs until its owner is dropped).
    pub fn stopped(&self) -> bool {
        self.thread.as_ref().is_none_or(JoinHandle::is_finished)
    }

    /// The job submitted last, done (spinning until it is).
    ///
    /// # Panics
    /// When the thread stopped without finishing it: it panicked, and its panic message has
    /// been printed.
    pub fn wait(&mut self) -> J {
        let mut spins = 0u32;
        while self.shared.state.load(Ordering::Acquire) != DONE {
            std::hint::spin_loop();
            spins = spins.wrapping_add(1);
            if spins % SPINS_PER_LOOK == 0
                && self.thread.as_ref().is_none_or(JoinHandle::is_finished)
            {
                panic!("the full network's second thread stopped during a job (it panicked)");
            }
        }
        let job = self.shared.take().expect("a done job is in the slot");
        self.shared.state.store(IDLE, Ordering::Release);
        job
    }
}

impl<J: Send + 'static> Drop for Handoff<J> {
    fn drop(&mut self) {
        self.shared.state.store(QUIT, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            thread.thread().unpark();
            // A panic in the thread was reported by `wait` already (or happened after the
            // last job); nothing more to say here.
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every job comes back done, in order, each exactly once, also after the thread has
    /// parked for want of work.
    #[test]
    fn every_job_comes_back_done_also_after_the_thread_parked() {
        let mut handoff = Handoff::new(|job: Vec<u64>| job.into_iter().map(|x| x * 3).collect());
        for round in 0..200u64 {
            handoff.submit(vec![round, round + 1]);
            assert_eq!(handoff.wait(), vec![3 * round, 3 * round + 3]);
        }
        thread::sleep(PARK_AFTER + Duration::from_millis(20));
        handoff.submit(vec![7]);
        assert_eq!(handoff.wait(), vec![21]);
    }

    /// A job that panics in the thread makes `wait` panic with a sentence, instead of
    /// spinning for ever.
    #[test]
    #[should_panic(expected = "second thread stopped")]
    fn a_panic_in_the_thread_is_reported_by_wait() {
        let mut handoff = Handoff::new(|job: u32| {
            assert!(job != 13, "deliberate");
            job
        });
        handoff.submit(13);
        handoff.wait();
    }
}
