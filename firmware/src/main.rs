//! slipguard firmware, first light: clocks, a blinking status LED, a defmt heartbeat and the
//! user button, on an embassy executor.
//!
//! Board: Olimex STM32-H405 (STM32F405RGT6, 8 MHz crystal); see `README.md` for the pins.
//! The inference core (`slipguard-core`) is linked in; the sensor pipeline comes next.
#![no_std]
#![no_main]

use defmt::info;
use embassy_executor::Spawner;
use embassy_stm32::exti::{self, ExtiInput};
use embassy_stm32::gpio::{Level, Output, Pull, Speed};
use embassy_stm32::time::Hertz;
use embassy_stm32::{bind_interrupts, interrupt};
use embassy_time::{Instant, Timer};
use {defmt_rtt as _, panic_probe as _};

bind_interrupts!(struct Irqs {
    EXTI0 => exti::InterruptHandler<interrupt::typelevel::EXTI0>;
});

/// Heartbeat period; the LED toggles every half period.
const HEARTBEAT_MS: u64 = 1000;

/// 168 MHz SYSCLK from the 8 MHz crystal:
/// HSE 8 MHz / M 4 = 2 MHz VCO input, × N 168 = 336 MHz VCO,
/// / P 2 = 168 MHz SYSCLK (AHB / 1 = HCLK 168 MHz, APB1 / 4 = 42 MHz, APB2 / 2 = 84 MHz),
/// / Q 7 = 48 MHz for USB OTG FS and SDIO. embassy sets 5 flash wait states for 168 MHz.
fn clock_config() -> embassy_stm32::Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(8_000_000),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll_src = PllSource::HSE;
    config.rcc.pll = Some(Pll {
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL168,
        divp: Some(PllPDiv::DIV2),
        divq: Some(PllQDiv::DIV7),
        divr: None,
    });
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV4;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.sys = Sysclk::PLL1_P;
    config
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clock_config());
    info!(
        "slipguard firmware {} up: SYSCLK {} Hz, core MAX_HIDDEN = {}, MAX_INPUT = {}",
        env!("CARGO_PKG_VERSION"),
        embassy_stm32::rcc::clocks(&p.RCC)
            .sys
            .to_hertz()
            .map_or(0, |h| h.0),
        slipguard_core::MAX_HIDDEN,
        slipguard_core::MAX_INPUT,
    );

    // User button "BUT" on PA0 (pressed = high, external pull-down on the board).
    let button = ExtiInput::new(p.PA0, p.EXTI0, Pull::Down, Irqs);
    spawner.spawn(button_task(button).expect("button task already spawned"));

    // Status LED "STAT" on PC12.
    let mut led = Output::new(p.PC12, Level::Low, Speed::Low);
    let mut beat: u32 = 0;
    loop {
        led.set_high();
        Timer::after_millis(HEARTBEAT_MS / 2).await;
        led.set_low();
        Timer::after_millis(HEARTBEAT_MS / 2).await;
        beat = beat.wrapping_add(1);
        info!("heartbeat {} at {} ms", beat, Instant::now().as_millis());
    }
}

/// Logs each press of the user button (EXTI0, rising edge).
#[embassy_executor::task]
async fn button_task(mut button: ExtiInput<'static, embassy_stm32::mode::Async>) {
    loop {
        button.wait_for_rising_edge().await;
        info!("button pressed at {} ms", Instant::now().as_millis());
        button.wait_for_falling_edge().await;
    }
}
