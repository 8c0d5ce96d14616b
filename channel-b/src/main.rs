//! Firmware image of channel B (STM32F405RG): initialises the board and runs the channel.
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
    use channel_b::role::ChannelB;
    #[cfg(feature = "hw")]
    use defmt_rtt as _;
    #[cfg(all(feature = "qemu", not(feature = "hw")))]
    use defmt_semihosting as _;
    use embassy_executor::Spawner;
    use safety_device as device;

    #[embassy_executor::main]
    async fn main(_spawner: Spawner) {
        defmt::info!("channel {=char}", channel_b::CHANNEL);
        let Ok(device) = Device::built(|id| device::config(id, device::CHANNEL_B_NAME)) else {
            panic!("SAFETY_NODE_ID must be 1..=127");
        };
        #[cfg_attr(
            feature = "hw",
            expect(unused_mut, reason = "only QEMU widens the window")
        )]
        let mut role = match ChannelB::new(&[(0x6000, 1, 1)]) {
            Ok(role) => role,
            Err(_) => panic!("channel B input table"),
        };
        // Under QEMU channel A's announcement of a plain frame can reach channel B tens of
        // milliseconds after the frame itself: channel B waits up to the QEMU window for it,
        // and channel A's link supervision follows the same window (its main). On hardware the
        // default applies: no tolerance of the hardware image changes.
        #[cfg(all(feature = "qemu", not(feature = "hw")))]
        role.set_window(dual_channel::runtime::QEMU_SAMPLE_WINDOW);
        // SimpleCAN's Model A (docs/simplecan.md section 13): channel B computes each packet of
        // the node and must hear channel A's on the bus within the packet's slot (1 ms), a sync
        // within 2 ms, not ahead of B's time by more than 200 µs. Under QEMU the SimpleCAN
        // images pace their clocks with a lookahead of 500 µs and a grant every 250 µs
        // (`board::qemu::LOOKAHEAD`, `GRANT_PERIOD`): A's packet can appear by B's clock up to
        // 2L + G + a frame time after B's own, 1,520 µs, and A's sync be ahead by 2L, 1 ms
        // (`Bounds::paced`, derived in docs/emulation.md). The hardware image keeps the
        // standard's bounds.
        #[cfg(all(feature = "qemu", not(feature = "hw"), feature = "simplecan"))]
        role.set_simplecan_bounds(dual_channel::simplecan::Bounds::paced(
            board::qemu::LOOKAHEAD,
            board::qemu::GRANT_PERIOD,
        ));
        run::<_, { board::SRDOS }>(device, role).await
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("channel-b is firmware for the STM32F405RG: build it with `cargo xtask build`");
}
