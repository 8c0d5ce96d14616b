//! Firmware image of channel A (STM32F405RG): initialises the board and runs the channel.
//!
//! `main` hands the device description, how to make the channel's role and the static slot
//! of the channel's runtime to the board layer's `run`, which initialises the board, runs the
//! self-tests and then runs the channel loop until reset: one loop that sleeps (`wfi`) until
//! a frame, link bytes or its next instant, no async executor (interrupts only move link bytes
//! and wake it; `board::hw`).
//!
//! Built for `thumbv7em-none-eabihf` by `cargo xtask build`; on the host this binary only
//! says so, so that `cargo clippy --workspace` covers the crate. The node-ID comes from the
//! board's switches.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod firmware {
    use board::Device;
    use board::hw::{RuntimeSlot, run};
    use channel_a::role::ChannelA;
    use defmt_rtt as _;
    use safety_device as device;

    /// The channel's runtime, built by the board layer's `run`: a static, counted in RAM when
    /// the image is linked.
    static RUNTIME: RuntimeSlot<ChannelA, { board::SRDOS }> = RuntimeSlot::new();

    #[cortex_m_rt::entry]
    fn main() -> ! {
        defmt::info!("channel {=char}", channel_a::CHANNEL);
        let Ok(device) = Device::built(|id| device::config(id, device::CHANNEL_A_NAME)) else {
            panic!("SAFETY_NODE_ID must be 1..=127");
        };
        run(device, ChannelA::default, &RUNTIME)
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("channel-a is firmware for the STM32F405RG: build it with `cargo xtask build`");
}
