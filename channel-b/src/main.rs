//! Firmware image of channel B (STM32F405RG). Skeleton: boots, logs and idles.
//!
//! Built for `thumbv7em-none-eabihf` by `cargo xtask build`; on the host this binary only
//! says so, so that `cargo clippy --workspace` covers the crate.
#![cfg_attr(target_os = "none", no_std, no_main)]

#[cfg(target_os = "none")]
mod firmware {
    use defmt_rtt as _;
    use panic_probe as _;

    #[cortex_m_rt::entry]
    fn main() -> ! {
        defmt::info!("channel {=char}: skeleton image", channel_b::CHANNEL);
        loop {
            cortex_m::asm::wfi();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("channel-b is firmware for the STM32F405RG: build it with `cargo xtask build`");
}
