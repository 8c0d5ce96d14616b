//! The STM32F405's memory map (RM0090 2.3, Table 1, and the Cortex-M4's private peripheral
//! bus, ARMv7-M B3.1): where the emulated memories are, and the names of the blocks, so that
//! a sentence about an access no model claims can say what the image was reaching for.

/// Flash, 1 Mbyte (RM0090 3.3).
pub const FLASH: u32 = 0x0800_0000;
/// Flash size.
pub const FLASH_SIZE: u32 = 0x10_0000;
/// Flash, system memory or SRAM aliased at 0, by the BOOT pins (RM0090 2.4): flash on this
/// board (BOOT0 low).
pub const BOOT_ALIAS: u32 = 0x0000_0000;
/// CCM data RAM, 64 Kbytes, data only: the core cannot fetch instructions from it (RM0090
/// 2.3.1).
pub const CCM: u32 = 0x1000_0000;
/// CCM size.
pub const CCM_SIZE: u32 = 0x1_0000;
/// SRAM1 (112 Kbytes) and SRAM2 (16 Kbytes), contiguous (RM0090 2.3.1).
pub const SRAM: u32 = 0x2000_0000;
/// SRAM1 and SRAM2 together.
pub const SRAM_SIZE: u32 = 0x2_0000;
/// Unicorn maps whole pages; peripheral blocks share them.
pub const PAGE: u32 = 0x1000;

/// Whether `address` is in SRAM1/2 or the CCM RAM.
pub fn is_ram(address: u32) -> bool {
    (SRAM..SRAM + SRAM_SIZE).contains(&address) || (CCM..CCM + CCM_SIZE).contains(&address)
}

/// The blocks of RM0090 Table 1 (STM32F405/407) and the private peripheral bus, by base and
/// size.
const BLOCKS: &[(u32, u32, &str)] = &[
    (0x0000_0000, 0x10_0000, "the boot alias of flash"),
    (0x0800_0000, 0x10_0000, "flash"),
    (0x1000_0000, 0x1_0000, "CCM data RAM"),
    (0x1FFF_0000, 0x7800, "system memory (the bootloader)"),
    (0x1FFF_7800, 0x210, "the OTP area"),
    (0x1FFF_7A10, 0x0C, "the unique device ID"),
    (0x1FFF_7A22, 0x02, "the flash size register"),
    (0x1FFF_C000, 0x10, "the option bytes"),
    (0x2000_0000, 0x2_0000, "SRAM1/SRAM2"),
    (0x2200_0000, 0x200_0000, "the SRAM bit-band alias"),
    (0x4000_0000, 0x400, "TIM2"),
    (0x4000_0400, 0x400, "TIM3"),
    (0x4000_0800, 0x400, "TIM4"),
    (0x4000_0C00, 0x400, "TIM5"),
    (0x4000_1000, 0x400, "TIM6"),
    (0x4000_1400, 0x400, "TIM7"),
    (0x4000_1800, 0x400, "TIM12"),
    (0x4000_1C00, 0x400, "TIM13"),
    (0x4000_2000, 0x400, "TIM14"),
    (0x4000_2800, 0x400, "RTC and backup registers"),
    (0x4000_2C00, 0x400, "WWDG"),
    (0x4000_3000, 0x400, "IWDG"),
    (0x4000_3400, 0x400, "I2S2ext"),
    (0x4000_3800, 0x400, "SPI2/I2S2"),
    (0x4000_3C00, 0x400, "SPI3/I2S3"),
    (0x4000_4000, 0x400, "I2S3ext"),
    (0x4000_4400, 0x400, "USART2"),
    (0x4000_4800, 0x400, "USART3"),
    (0x4000_4C00, 0x400, "UART4"),
    (0x4000_5000, 0x400, "UART5"),
    (0x4000_5400, 0x400, "I2C1"),
    (0x4000_5800, 0x400, "I2C2"),
    (0x4000_5C00, 0x400, "I2C3"),
    (0x4000_6400, 0x400, "CAN1"),
    (0x4000_6800, 0x400, "CAN2"),
    (0x4000_7000, 0x400, "PWR"),
    (0x4000_7400, 0x400, "DAC"),
    (0x4001_0000, 0x400, "TIM1"),
    (0x4001_0400, 0x400, "TIM8"),
    (0x4001_1000, 0x400, "USART1"),
    (0x4001_1400, 0x400, "USART6"),
    (0x4001_2000, 0x400, "ADC1/ADC2/ADC3"),
    (0x4001_2C00, 0x400, "SDIO"),
    (0x4001_3000, 0x400, "SPI1"),
    (0x4001_3800, 0x400, "SYSCFG"),
    (0x4001_3C00, 0x400, "EXTI"),
    (0x4001_4000, 0x400, "TIM9"),
    (0x4001_4400, 0x400, "TIM10"),
    (0x4001_4800, 0x400, "TIM11"),
    (0x4002_0000, 0x400, "GPIOA"),
    (0x4002_0400, 0x400, "GPIOB"),
    (0x4002_0800, 0x400, "GPIOC"),
    (0x4002_0C00, 0x400, "GPIOD"),
    (0x4002_1000, 0x400, "GPIOE"),
    (0x4002_1400, 0x400, "GPIOF"),
    (0x4002_1800, 0x400, "GPIOG"),
    (0x4002_1C00, 0x400, "GPIOH"),
    (0x4002_2000, 0x400, "GPIOI"),
    (0x4002_3000, 0x400, "CRC"),
    (0x4002_3800, 0x400, "RCC"),
    (0x4002_3C00, 0x400, "the flash interface registers"),
    (0x4002_4000, 0x1000, "backup SRAM"),
    (0x4002_6000, 0x400, "DMA1"),
    (0x4002_6400, 0x400, "DMA2"),
    (0x4002_8000, 0x1400, "Ethernet MAC"),
    (0x4004_0000, 0x4_0000, "USB OTG HS"),
    (0x4200_0000, 0x200_0000, "the peripheral bit-band alias"),
    (0x5000_0000, 0x4_0000, "USB OTG FS"),
    (0x5005_0000, 0x400, "DCMI"),
    (0x5006_0000, 0x400, "CRYP"),
    (0x5006_0400, 0x400, "HASH"),
    (0x5006_0800, 0x400, "RNG"),
    (0xA000_0000, 0x1000, "FSMC control registers"),
    (0xE000_0000, 0x1000, "ITM"),
    (0xE000_1000, 0x1000, "DWT"),
    (0xE000_2000, 0x1000, "FPB"),
    (
        0xE000_E000,
        0x1000,
        "the System Control Space (SCB, NVIC, SysTick)",
    ),
    (0xE004_0000, 0x1000, "TPIU"),
    (0xE004_2000, 0x1000, "DBGMCU"),
];

/// What is at `address` on the F405 (`None`: a reserved area).
pub fn describe(address: u32) -> Option<&'static str> {
    BLOCKS
        .iter()
        .find(|(base, size, _)| (*base..base.saturating_add(*size)).contains(&address))
        .map(|(_, _, name)| *name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rm0090_2_3_blocks_are_named_by_address() {
        assert_eq!(describe(0x4000_6400), Some("CAN1"));
        assert_eq!(describe(0x4002_3C14), Some("the flash interface registers"));
        assert_eq!(describe(0x3000_0000), None);
        assert!(is_ram(0x2001_FFFF));
        assert!(!is_ram(0x2002_0000));
    }
}
