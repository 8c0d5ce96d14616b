//! Firmware image of channel B (STM32F405RG): initialises the board and runs the channel.
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
    use channel_b::role::ChannelB;
    use defmt_rtt as _;
    use safety_device as device;

    /// The channel's runtime, built by the board layer's `run`: a static, counted in RAM when
    /// the image is linked.
    static RUNTIME: RuntimeSlot<ChannelB, { board::SRDOS }> = RuntimeSlot::new();

    #[cortex_m_rt::entry]
    fn main() -> ! {
        defmt::info!("channel {=char}", channel_b::CHANNEL);
        let Ok(device) = Device::built(|id| device::config(id, device::CHANNEL_B_NAME)) else {
            panic!("SAFETY_NODE_ID must be 1..=127");
        };
        // Built by the board layer where it starts the runtime, not in this frame, which
        // stays on the stack for as long as the channel runs. SimpleCAN's Model A
        // (docs/simplecan.md section 13): channel B computes each packet of the node and must
        // hear channel A's on the bus within the packet's slot, and a sync within its bound:
        // the image keeps the standard's bounds (`Bounds::STANDARD`).
        let role = || match ChannelB::new(&[(0x6000, 1, 1)]) {
            Ok(role) => role,
            Err(_) => panic!("channel B input table"),
        };
        run(device, role, &RUNTIME)
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("channel-b is firmware for the STM32F405RG: build it with `cargo xtask build`");
}
