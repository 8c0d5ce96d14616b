//! An emulated STM32F405: the Cortex-M4 instruction set executed by `unicorn-engine`
//! (Unicorn 2, QEMU's code generator), the Cortex-M4 system part Unicorn lacks (NVIC,
//! exception entry and return, SysTick, SCB, WFI/WFE) modelled from the ARMv7-M Architecture
//! Reference Manual, and the F405 peripherals the hardware layer touches modelled from
//! RM0090, so that the sealed hardware images run unchanged.
//!
//! Layers:
//! - [`peripherals`]: one small model per peripheral block, pure logic (no Unicorn), each
//!   citing its RM0090 section and tested against the manual's statements;
//! - [`system`]: the Cortex-M4's System Control Space (NVIC, SCB, SysTick, DWT), pure logic;
//! - [`cpu`]: Unicorn, exception entry and return, sleep, and the memory map that routes
//!   every access to the model that claims it (an access no model claims stops the run with
//!   a sentence, [`stop`]);
//! - [`image`], [`rtt`], [`log`]: the sealed image loaded, its defmt log drained from RTT and
//!   decoded;
//! - [`network`]: MCUs on one CAN bus in one virtual time; [`control`]: its control port;
//!   [`tool_port`] and [`cases`]: the configuration tool's library on it in-process;
//!   [`socketcand`]: separate programs on it over TCP, on a virtual time that follows the host
//!   clock.

pub mod cases;
pub mod control;
pub mod cpu;
pub mod e2e;
pub mod figures;
pub mod image;
pub mod log;
pub mod memory;
pub mod network;
pub mod observed;
pub mod peripherals;
pub mod profile;
pub mod rtt;
pub mod scenario;
pub mod socketcand;
pub mod stop;
pub mod system;
pub mod time;
pub mod tool_port;
