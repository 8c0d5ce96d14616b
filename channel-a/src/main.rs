//! Firmware image of channel A (STM32F405RG). Skeleton: boots, logs and idles.
//!
//! Built for `thumbv7em-none-eabihf` by `cargo xtask build`; on the host this binary only
//! says so, so that `cargo clippy --workspace` covers the crate.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod firmware {
    use defmt_rtt as _;
    use panic_probe as _;

    /// The RAM per SRDO of this image's protocol core, kept in the image so that
    /// `cargo xtask bench` reports the figure for the real target, not the host.
    #[used]
    #[unsafe(no_mangle)]
    static SHARED_RAM_PER_SRDO: u32 = shared::node::RAM_PER_SRDO as u32;

    #[cortex_m_rt::entry]
    fn main() -> ! {
        defmt::info!("channel {=char}: skeleton image", channel_a::CHANNEL);
        loop {
            cortex_m::asm::wfi();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("channel-a is firmware for the STM32F405RG: build it with `cargo xtask build`");
}
