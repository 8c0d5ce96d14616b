//! Child processes that end with `cargo xtask`: the one place that starts the long-running
//! ones (the emulated network, the hub, the socketcand simulation, python scripts) and ends them.
//!
//! Each [`Guarded`] child runs in its own process group, so that a Ctrl-C on the terminal
//! reaches `cargo xtask` alone and the order of the ending is ours, and its whole group
//! (e.g. `timeout` and the program it runs) is killed when the guard is dropped: on return, on
//! an error, on a panic. What a drop cannot cover is xtask ended by a signal: SIGINT,
//! SIGTERM and SIGHUP end a process without running destructors. [`end_with_xtask`]
//! installs the one handler for them (the `ctrlc` crate, feature `termination`): it kills
//! every child still guarded, then exits with 130; a task that ends itself in order on a
//! signal (`cargo xtask run`, which prints its summary) registers that instead with
//! [`on_interrupt`]. SIGKILL cannot be caught: a child outlives an xtask killed that way.
//! (`prctl(PR_SET_PDEATHSIG)` would cover it, but only from `pre_exec`, which is `unsafe`,
//! and the house keeps `unsafe` to the board layer.)

use nix::sys::signal::{Signal, killpg};
use nix::unistd::Pid;
use std::collections::BTreeSet;
use std::os::unix::process::CommandExt as _;
use std::process::{Child, Command};
use std::sync::Mutex;

/// The process groups of the children alive and guarded (each child leads its own).
pub struct Registry(Mutex<BTreeSet<u32>>);

impl Registry {
    pub const fn new() -> Self {
        Registry(Mutex::new(BTreeSet::new()))
    }

    fn set(&self) -> std::sync::MutexGuard<'_, BTreeSet<u32>> {
        // A panic while holding the lock leaves the set as it was: still the truth.
        self.0
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Kills every group still registered (the signal handler's work). The children stay
    /// registered until their guard reaps them.
    pub fn kill_all(&self) {
        for &group in self.set().iter() {
            kill_group(group);
        }
    }
}

/// xtask's children.
static CHILDREN: Registry = Registry::new();

/// What the signal handler does instead of killing and exiting, when a task asked for it.
static ON_INTERRUPT: Mutex<Option<Box<dyn Fn() + Send>>> = Mutex::new(None);

fn kill_group(group: u32) {
    if let Ok(group) = i32::try_from(group) {
        // ESRCH: the group has ended already.
        let _ = killpg(Pid::from_raw(group), Signal::SIGKILL);
    }
}

/// A child process in its own process group, killed with its group when dropped.
///
/// Every reaping goes through the guard ([`Guarded::try_wait`], [`Guarded::end`]) and takes
/// the child out of the registry under its lock: a process ID is signalled only while its
/// child has not been reaped, so it cannot be another process's by then. A child that has
/// exited by itself is not signalled at all (its group may be gone and its ID reused); the
/// children here leave nothing behind them when they exit (`timeout` waits for its command).
pub struct Guarded {
    child: Child,
    registry: &'static Registry,
}

impl Guarded {
    /// Starts `command` as a guarded child of xtask.
    pub fn spawn(command: &mut Command) -> std::io::Result<Guarded> {
        Guarded::spawn_in(command, &CHILDREN)
    }

    fn spawn_in(command: &mut Command, registry: &'static Registry) -> std::io::Result<Guarded> {
        // The registry is held across the start, so that the handler never misses a child
        // that has started but is not registered yet.
        let mut set = registry.set();
        let child = command.process_group(0).spawn()?;
        set.insert(child.id());
        Ok(Guarded { child, registry })
    }

    /// Its standard output, when it was piped (once).
    pub fn take_stdout(&mut self) -> Option<std::process::ChildStdout> {
        self.child.stdout.take()
    }

    /// Its exit status, if it has exited (reaped then, and forgotten).
    pub fn try_wait(&mut self) -> std::io::Result<Option<std::process::ExitStatus>> {
        let mut set = self.registry.set();
        let status = self.child.try_wait()?;
        if status.is_some() {
            set.remove(&self.child.id());
        }
        Ok(status)
    }

    /// Kills the child's process group unless the child has exited, and reaps it; again, it
    /// does nothing.
    pub fn end(&mut self) {
        let mut set = self.registry.set();
        if set.remove(&self.child.id()) {
            if let Ok(None) = self.child.try_wait() {
                kill_group(self.child.id());
            }
            let _ = self.child.wait();
        }
    }
}

impl Drop for Guarded {
    fn drop(&mut self) {
        self.end();
    }
}

/// Installs xtask's one handler of SIGINT, SIGTERM and SIGHUP: every guarded child is
/// killed and xtask exits with 130, unless a task registered its own ending with
/// [`on_interrupt`].
pub fn end_with_xtask() -> anyhow::Result<()> {
    ctrlc::set_handler(|| {
        let own = ON_INTERRUPT
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        match own.as_ref() {
            Some(end) => end(),
            None => {
                CHILDREN.kill_all();
                eprintln!("xtask: interrupted; every child process ended");
                std::process::exit(130);
            }
        }
    })?;
    Ok(())
}

/// From now on a signal calls `end` instead of killing the children and exiting: the task
/// ends itself in order, and its guards end the children.
pub fn on_interrupt(end: impl Fn() + Send + 'static) {
    *ON_INTERRUPT
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner()) = Some(Box::new(end));
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::BufRead as _;
    use std::process::Stdio;

    /// Whether process `pid` still runs: neither gone nor a zombie. A process killed by
    /// SIGKILL is a zombie from then on; its parent (here, for an orphan, init) reaps it.
    fn running(pid: u32) -> bool {
        match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
            // `pid (comm) S ...`: the state follows the last parenthesis.
            Ok(stat) => stat
                .rsplit_once(')')
                .is_some_and(|(_, rest)| !rest.trim_start().starts_with(['Z', 'X'])),
            Err(_) => false,
        }
    }

    /// Waits until `pid` no longer runs, for at most 5 s: the kernel delivers the signal
    /// after `killpg` has returned. (A bound on the wait, not on the time it takes.)
    fn ended(pid: u32) -> bool {
        (0..500).any(|_| {
            let gone = !running(pid);
            if !gone {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            gone
        })
    }

    /// A shell that starts a grandchild (`sleep`) and prints its process ID: (guard, the
    /// grandchild's ID).
    fn with_grandchild(registry: &'static Registry) -> (Guarded, u32) {
        let mut shell = Guarded::spawn_in(
            Command::new("sh")
                .args(["-c", "sleep 600 & echo $!; wait"])
                .stdout(Stdio::piped()),
            registry,
        )
        .expect("sh starts");
        let stdout = shell.take_stdout().expect("piped");
        let mut line = String::new();
        std::io::BufReader::new(stdout)
            .read_line(&mut line)
            .expect("the grandchild's ID");
        let grandchild = line.trim().parse().expect("a process ID");
        (shell, grandchild)
    }

    /// The guard kills its child and the child's own children when dropped, reaps it and
    /// forgets it.
    #[test]
    fn a_dropped_guard_ends_its_child_and_the_childs_children() {
        static REGISTRY: Registry = Registry::new();
        let (shell, grandchild) = with_grandchild(&REGISTRY);
        let pid = shell.child.id();
        assert!(running(pid) && running(grandchild));
        assert!(REGISTRY.set().contains(&pid));
        drop(shell);
        assert!(!running(pid), "reaped by the drop");
        assert!(ended(grandchild), "the grandchild {grandchild} still runs");
        assert!(REGISTRY.set().is_empty());
    }

    /// What the signal handler does: every child still guarded is killed (before any guard
    /// is dropped), and the guard's own ending afterwards is harmless.
    #[test]
    fn the_signal_handlers_kill_ends_every_guarded_child() {
        static REGISTRY: Registry = Registry::new();
        let (mut first, grandchild) = with_grandchild(&REGISTRY);
        let mut second =
            Guarded::spawn_in(Command::new("sleep").arg("600"), &REGISTRY).expect("sleep starts");
        REGISTRY.kill_all();
        for child in [&mut first, &mut second] {
            let status = (0..500)
                .find_map(|_| {
                    let status = child.try_wait().expect("try_wait");
                    if status.is_none() {
                        std::thread::sleep(std::time::Duration::from_millis(10));
                    }
                    status
                })
                .expect("killed");
            assert_eq!(
                std::os::unix::process::ExitStatusExt::signal(&status),
                Some(9)
            );
        }
        assert!(ended(grandchild), "the grandchild {grandchild} still runs");
        first.end();
        first.end();
        drop(second);
        assert!(REGISTRY.set().is_empty());
    }
}
