//! Firmware image of channel A (STM32F405RG): initialises the board and runs the channel.
//!
//! `main` builds the channel's role and hands it to the board layer's `run`, which
//! initialises the board, runs the self-tests and then runs the channel loop in the main task
//! itself, the image's only task (interrupts fill and empty the link USART's queues). A separate channel task was tried and
//! measured: its future was moved through the stack once more, and the deepest stack grew
//! past the stack reserve (`docs/footprint.md`).
//!
//! Built for `thumbv7em-none-eabihf` by `cargo xtask build`; on the host this binary only
//! says so, so that `cargo clippy --workspace` covers the crate. On hardware the node-ID comes
//! from the board's switches; under QEMU from the `node=N` argument, else `SAFETY_NODE_ID` at
//! build time (default 1).
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod firmware {
    use board::Device;
    #[cfg(feature = "hw")]
    use board::hw::run;
    #[cfg(all(feature = "qemu", not(feature = "hw")))]
    use board::qemu::run;
    use channel_a::role::ChannelA;
    #[cfg(feature = "hw")]
    use defmt_rtt as _;
    #[cfg(all(feature = "qemu", not(feature = "hw")))]
    use defmt_semihosting as _;
    use embassy_executor::Spawner;
    use safety_device as device;

    #[embassy_executor::main]
    async fn main(_spawner: Spawner) {
        defmt::info!("channel {=char}", channel_a::CHANNEL);
        let Ok(device) = Device::built(|id| device::config(id, device::CHANNEL_A_NAME)) else {
            panic!("SAFETY_NODE_ID must be 1..=127");
        };
        #[cfg_attr(
            feature = "hw",
            expect(unused_mut, reason = "only QEMU widens the window")
        )]
        let mut role = ChannelA::default();
        // Channel B's image widens its window under QEMU: this channel's link latency
        // supervision holds the round trip to the bound of the same window.
        #[cfg(all(feature = "qemu", not(feature = "hw")))]
        role.set_announcement_window(dual_channel::runtime::QEMU_SAMPLE_WINDOW);
        run::<_, { board::SRDOS }>(device, role).await
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("channel-a is firmware for the STM32F405RG: build it with `cargo xtask build`");
}
