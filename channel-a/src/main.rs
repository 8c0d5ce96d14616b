//! Firmware image of channel A (STM32F405RG): initialises the board and runs the channel.
//!
//! Built for `thumbv7em-none-eabihf` by `cargo xtask build`; on the host this binary only
//! says so, so that `cargo clippy --workspace` covers the crate. The node-ID is taken from
//! `SAFETY_NODE_ID` at build time (default 1; under QEMU the `node=N` argument overrides it);
//! a real device reads it from its switches.
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
    use dual_channel::device;
    use embassy_executor::Spawner;
    use panic_probe as _;

    #[embassy_executor::main]
    async fn main(spawner: Spawner) {
        defmt::info!("channel {=char}", channel_a::CHANNEL);
        let Ok(device) = Device::built(|id| device::config(id, "safety node, channel A")) else {
            panic!("SAFETY_NODE_ID must be 1..=127");
        };
        let role = ChannelA::default();
        run::<_, 4>(spawner, device, role).await
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("channel-a is firmware for the STM32F405RG: build it with `cargo xtask build`");
}
