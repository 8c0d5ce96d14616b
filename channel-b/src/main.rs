//! Firmware image of channel B (STM32F405RG): initialises the board and runs the channel.
//!
//! Built for `thumbv7em-none-eabihf` by `cargo xtask build`; on the host this binary only
//! says so, so that `cargo clippy --workspace` covers the crate. The node-ID is taken from
//! `SAFETY_NODE_ID` at build time (default 1; under QEMU the `node=N` argument overrides it);
//! a real device reads it from its switches.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod firmware {
    #[cfg(feature = "hw")]
    use board::hw::run;
    #[cfg(all(feature = "qemu", not(feature = "hw")))]
    use board::qemu::run;
    use board::{Device, InputObjects};
    use channel_b::role::ChannelB;
    #[cfg(feature = "hw")]
    use defmt_rtt as _;
    #[cfg(all(feature = "qemu", not(feature = "hw")))]
    use defmt_semihosting as _;
    use dual_channel::device;
    use embassy_executor::Spawner;
    use panic_probe as _;
    use shared::canopen::NodeId;

    /// The RAM per SRDO of this image's protocol core, kept in the image so that
    /// `cargo xtask bench` reports the figure for the real target, not the host.
    #[used]
    #[unsafe(no_mangle)]
    static SHARED_RAM_PER_SRDO: u32 = shared::node::RAM_PER_SRDO as u32;

    /// The node-ID this image was built for.
    fn node_id() -> NodeId {
        let raw = option_env!("SAFETY_NODE_ID")
            .and_then(|text| text.parse::<u8>().ok())
            .unwrap_or(1);
        match NodeId::new(raw) {
            Ok(id) => id,
            Err(_) => panic!("SAFETY_NODE_ID must be 1..=127"),
        }
    }

    #[embassy_executor::main]
    async fn main(spawner: Spawner) {
        defmt::info!(
            "channel {=char}: node {=u8}",
            channel_b::CHANNEL,
            node_id().raw()
        );
        let role = match ChannelB::new(&[(0x6000, 1, 1)]) {
            Ok(role) => role,
            Err(_) => panic!("channel B input table"),
        };
        let device = Device {
            describe: |id| device::config(id, "safety node, channel B"),
            default_id: node_id(),
            inputs: InputObjects {
                plain: device::INPUT,
                inverted: device::INPUT_INVERTED,
            },
        };
        run::<_, 4>(spawner, device, role).await
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("channel-b is firmware for the STM32F405RG: build it with `cargo xtask build`");
}
