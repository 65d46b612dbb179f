//! slipguard firmware: samples the sensors, predicts on every channel every frame, streams flag
//! frames to the hand controller and answers its commands.
//!
//! Board: Olimex STM32-H405 (STM32F405RGT6, 8 MHz crystal) or an STM32F446RE (feature
//! `stm32f446re`); pins in `README.md`. This file is only the board layer; the logic is
//! `slipguard-app` (tested on the host, and run unchanged under QEMU by `qemu-app`):
//!
//! ```text
//! TIM2 TRGO ─▶ ADC1 scan (16 or 4 ch) ─DMA2 S0 ring─▶ adc_task: Frontend (faults, FIR ÷16)
//!    ─▶ EVENTS ─▶ inference (main): App::infer/emit, deadline, DWT cycles, UNSTABLE pin, IWDG
//! USART1 RX ─DMA2 S2 ring─▶ rx_task ─▶ EVENTS (commands, in arrival order with the frames;
//!    model uploads into flash sectors 10/11 through slipguard_app::upload and BoardFlash)
//! inference ─▶ TX queue ─▶ tx_task ─DMA2 S7─▶ USART1 TX (COBS frames, docs/protocol.md)
//! ```
#![no_std]
#![no_main]

use core::sync::atomic::{AtomicU32, Ordering};

use defmt::{debug, error, info, warn};
use embassy_executor::Spawner;
use embassy_stm32::adc::{Adc, AdcChannel, Exten, RingBufferedAdc, SampleTime};
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::peripherals::{ADC1, IWDG, TIM2};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::low_level::{MasterMode, Timer as LlTimer};
use embassy_stm32::usart::{self, RingBufferedUartRx, Uart, UartTx};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{Peri, bind_interrupts, dma, peripherals};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_time::{Duration, Instant, Timer, with_timeout};
use slipguard_app::app::App;
use slipguard_app::frontend::{FrameInput, Frontend, SCANS_PER_FRAME};
use slipguard_app::profile::{AdcCode, Profile};
use slipguard_app::replay;
use slipguard_app::schedule::Deadline;
use slipguard_app::upload::{self, FlashError, Uploader};
use slipguard_core::model_ram::ModelRam;
use slipguard_core::protocol::{Deframer, Frame, MAX_WIRE};
use slipguard_core::units::Millihertz;
use slipguard_support::boot::ModelLine;
use static_cell::{ConstStaticCell, StaticCell};
use {defmt_rtt as _, panic_probe as _};

#[cfg(all(feature = "stm32f405rg", feature = "stm32f446re"))]
compile_error!("choose one chip feature: `--no-default-features --features stm32f446re`");

bind_interrupts!(struct Irqs {
    USART1 => usart::InterruptHandler<peripherals::USART1>;
    DMA2_STREAM0 => dma::InterruptHandler<peripherals::DMA2_CH0>;
    DMA2_STREAM2 => dma::InterruptHandler<peripherals::DMA2_CH2>;
    DMA2_STREAM7 => dma::InterruptHandler<peripherals::DMA2_CH7>;
});

/// The sensor profile of this build.
#[cfg(not(feature = "profile-suction"))]
const PROFILE: Profile = Profile::HAND;
#[cfg(feature = "profile-suction")]
const PROFILE: Profile = Profile::SUCTION;
const CHANNELS: usize = PROFILE.channels;

/// Link to the hand controller: USART1, 921 600 baud 8N1 (a 16-channel flag frame, 56 bytes on
/// the wire, takes 0.61 ms).
const BAUD: u32 = 921_600;
/// Independent watchdog timeout: fed once per frame (every ≤ 60 ms) and on the stall path; over
/// the 2 s a model-slot erase (128 KiB sector) may stall the CPU during an upload.
const WATCHDOG_US: u32 = 4_000_000;

// The MODEL flash region (default blob in the `.model` section, re-flashable on its own).
use slipguard_support::model::{DEFAULT_BLOB_LEN, region as model_region};

/// Bytes per model slot: one 128 KiB flash sector.
const SLOT_LEN: usize = 128 * 1024;

/// The two model slots for `slipguard_app::upload`: slot 1 is the MODEL region (the last sector,
/// holding the firmware image's default blob), slot 0 the sector before it (kept out of FLASH by
/// `memory.x`).
struct BoardFlash {
    flash: embassy_stm32::flash::Flash<'static, embassy_stm32::flash::Blocking>,
    /// Offset of slot 0 from the start of flash.
    base: u32,
}

impl BoardFlash {
    fn new(p: Peri<'static, peripherals::FLASH>) -> Self {
        let model = model_region().as_ptr() as u32;
        Self {
            flash: embassy_stm32::flash::Flash::new_blocking(p),
            base: (model - embassy_stm32::flash::FLASH_BASE as u32) - SLOT_LEN as u32,
        }
    }
    fn offset(&self, slot: u8) -> Option<u32> {
        (slot < upload::SLOTS).then(|| self.base + slot as u32 * SLOT_LEN as u32)
    }
    /// A slot as the CPU sees it (empty for an unknown slot).
    fn slot(&self, slot: u8) -> &'static [u8] {
        match self.offset(slot) {
            // SAFETY: both slots are whole sectors of the memory-mapped internal flash, outside
            // the FLASH region the program lives in. They change only through `erase`/`write`
            // on the *other* slot than the one the app runs from (an upload never writes the
            // active slot, and after a commit the board restarts), so a running model's bytes
            // never change under it.
            Some(at) => unsafe {
                core::slice::from_raw_parts(
                    (embassy_stm32::flash::FLASH_BASE as u32 + at) as *const u8,
                    SLOT_LEN,
                )
            },
            None => &[],
        }
    }
}

impl upload::Flash for BoardFlash {
    fn slot_len(&self) -> usize {
        SLOT_LEN
    }
    fn erase(&mut self, slot: u8) -> Result<(), FlashError> {
        let at = self.offset(slot).ok_or(FlashError::Erase)?;
        self.flash
            .blocking_erase(at, at + SLOT_LEN as u32)
            .map_err(|_| FlashError::Erase)
    }
    fn write(&mut self, slot: u8, offset: usize, data: &[u8]) -> Result<(), FlashError> {
        let at = self.offset(slot).ok_or(FlashError::Write)?;
        if offset + data.len() > SLOT_LEN {
            return Err(FlashError::Write);
        }
        self.flash
            .blocking_write(at + offset as u32, data)
            .map_err(|_| FlashError::Write)
    }
    fn read(&self, slot: u8) -> &[u8] {
        self.slot(slot)
    }
}

/// What the inference task receives, in arrival order.
enum Event {
    /// Bytes from the UART.
    Rx(heapless::Vec<u8, 32>),
    /// One frame's input and when it became available (µs since boot).
    Frame(FrameInput, u64),
}

type TxFrame = heapless::Vec<u8, MAX_WIRE>;

static EVENTS: Channel<CriticalSectionRawMutex, Event, 3> = Channel::new();
static TX: Channel<CriticalSectionRawMutex, TxFrame, 8> = Channel::new();
static APP: StaticCell<App<'static>> = StaticCell::new();
/// The model's RAM image (80 KiB of SRAM, `.bss`): the kernels read the weights from here, not
/// from flash (5 wait states). Not in CCM, so that a DMA stream could read it too.
static MODEL_RAM: ConstStaticCell<ModelRam> = ConstStaticCell::new(ModelRam::new());
/// Frames the ADC side could not queue (inference more than two frames behind) or lost to a DMA
/// overrun; the inference task moves them into the app's `skipped` counter.
static SKIPPED: AtomicU32 = AtomicU32::new(0);

/// DMA ring: two halves of one frame each (SCANS_PER_FRAME scans × CHANNELS).
const HALF: usize = SCANS_PER_FRAME * CHANNELS;
static ADC_RING: StaticCell<[u16; 2 * HALF]> = StaticCell::new();
static UART_RX_RING: StaticCell<[u8; 256]> = StaticCell::new();

/// 168 MHz SYSCLK from the 8 MHz HSE: / M 4 × N 168 / P 2 (APB1 42 MHz, APB2 84 MHz, timers on
/// both 84 / 168 MHz), / Q 7 = 48 MHz. The STM32F446RE could run 180 MHz; it keeps 168 so that
/// every budget holds on both parts (a Nucleo feeds HSE from the ST-LINK's 8 MHz MCO: bypass).
fn clock_config() -> embassy_stm32::Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(8_000_000),
        mode: if cfg!(feature = "stm32f446re") {
            HseMode::Bypass
        } else {
            HseMode::Oscillator
        },
    });
    config.rcc.pll_src = PllSource::HSE;
    config.rcc.pll = Some(Pll {
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL168,
        divp: Some(PllPDiv::DIV2),
        divq: Some(PllQDiv::DIV7),
        divr: if cfg!(feature = "stm32f446re") {
            Some(PllRDiv::DIV2)
        } else {
            None
        },
    });
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV4;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.sys = Sysclk::PLL1_P;
    config
}

/// TIM2 (32-bit) update events at `rate × 16` per second drive the ADC scans (TRGO = update).
fn start_scan_timer(tim: Peri<'static, TIM2>, rate_mhz: Millihertz) -> LlTimer<'static, TIM2> {
    let t = LlTimer::new(tim);
    let clk = t.get_clock_frequency().0 as u64;
    let scan_mhz = PROFILE.scan_rate_mhz(rate_mhz).0.max(1) as u64;
    // Period in timer ticks, rounded: 84 MHz / 267.2 Hz = 314 371 (error < 2 ppm).
    let ticks = ((clk * 1000 + scan_mhz / 2) / scan_mhz).clamp(2, u32::MAX as u64) as u32;
    let r = t.regs_gp32();
    r.psc().write_value(0);
    r.arr().write_value(ticks - 1);
    r.egr().write(|w| w.set_ug(true));
    t.set_master_mode(MasterMode::UPDATE);
    t.start();
    info!(
        "ADC trigger: TIM2 {} Hz / {} = {} mHz scans",
        clk,
        ticks,
        clk * 1_000_000 / ticks as u64 / 1000
    );
    t
}

/// Board layer, sampling side: one DMA half-buffer = one frame of scans into the front end.
#[embassy_executor::task]
async fn adc_task(mut rb: RingBufferedAdc<'static, ADC1>, mut frontend: Frontend) {
    let mut half = [0u16; HALF];
    // After an overrun the ring drops partial scans, so channel 0 stays at the start of a scan.
    rb.set_alignment(CHANNELS);
    rb.start();
    loop {
        match rb.read(&mut half).await {
            Ok(_) => frontend.push_block(AdcCode::from_dma(&half), |input| {
                let ev = Event::Frame(input, Instant::now().as_micros());
                if EVENTS.try_send(ev).is_err() {
                    SKIPPED.fetch_add(1, Ordering::Relaxed);
                }
            }),
            Err(_) => {
                // Samples were lost (the task fell a whole half-buffer behind): a frame's worth
                // at least. Count it; the ring resynchronises on whole scans by itself.
                SKIPPED.fetch_add(1, Ordering::Relaxed);
                warn!("ADC DMA overrun: frame skipped");
            }
        }
    }
}

/// Board layer, command side: bytes from the hand controller, in chunks, in arrival order.
#[embassy_executor::task]
async fn rx_task(mut rx: RingBufferedUartRx<'static>) {
    let mut buf = [0u8; 32];
    loop {
        match rx.read(&mut buf).await {
            Ok(n) if n > 0 => {
                let v = heapless::Vec::from_slice(&buf[..n]).unwrap_or_default();
                EVENTS.send(Event::Rx(v)).await;
            }
            Ok(_) => {}
            Err(e) => warn!("UART RX error {}", e),
        }
    }
}

/// Board layer, output side: frames to the UART by DMA.
#[embassy_executor::task]
async fn tx_task(mut tx: UartTx<'static, embassy_stm32::mode::Async>) {
    loop {
        let f = TX.receive().await;
        if let Err(e) = tx.write(&f).await {
            warn!("UART TX error {}", e);
        }
    }
}

/// Loads the model into RAM ([`upload::load`], the boot path the host tests run): validates
/// `blob` (the active model slot) and copies it into `ram` as the image the register-blocked
/// LSTM kernel reads. Returns the bytes the application runs: the RAM image, or `blob` itself if
/// it is bad (the application then reports why) or larger than the copy (it runs from flash,
/// slower). After an upload the board restarts, so boot calls this once with the new slot.
fn load_model_into_ram<'a>(ram: &'a mut ModelRam, blob: &'a [u8]) -> &'a [u8] {
    let capacity = ram.capacity();
    let (bytes, copied) = upload::load(ram, blob);
    match copied {
        Ok(()) => info!(
            "model copied to RAM at {:#010x}: {} of {} bytes",
            bytes.as_ptr() as usize,
            bytes.len(),
            capacity
        ),
        Err(e) => warn!("model stays in flash: {}", e),
    }
    bytes
}

/// Queues a frame for the UART; a full queue counts the frame as skipped.
fn send(app: &mut App<'_>, f: &Frame) {
    let mut buf = [0u8; MAX_WIRE];
    let n = replay::wire(f, &mut buf);
    let v = TxFrame::from_slice(&buf[..n]).unwrap_or_default();
    if TX.try_send(v).is_err() {
        app.note_skipped();
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clock_config());
    let mut cp = cortex_m::Peripherals::take().expect("core peripherals taken twice");
    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();
    let sysclk = embassy_stm32::rcc::clocks(&p.RCC)
        .sys
        .to_hertz()
        .map_or(0, |h| h.0);
    info!(
        "slipguard firmware {} ({}), profile {} ({} channels), SYSCLK {} Hz",
        env!("CARGO_PKG_VERSION"),
        if cfg!(feature = "stm32f446re") {
            "STM32F446RE"
        } else {
            "STM32F405RG"
        },
        PROFILE.name,
        CHANNELS,
        sysclk
    );

    // Watchdog first: whatever happens next, a hang resets the part.
    let mut wdg: IndependentWatchdog<'static, IWDG> = IndependentWatchdog::new(p.IWDG, WATCHDOG_US);
    wdg.unleash();

    // The model: the valid slot with the highest sequence number, checked at boot, faults
    // reported, never a crash.
    let mut flash = BoardFlash::new(p.FLASH);
    let active = upload::select(&flash, &PROFILE);
    let mut uploader = Uploader::new(active);
    match active {
        Some(a) => info!(
            "model slot {} (sequence {}, {} bytes)",
            a.slot, a.seq, a.len
        ),
        None => error!("no valid model in either slot: waiting for an upload"),
    }
    let blob = active
        .and_then(|a| flash.slot(a.slot).get(..a.len))
        .unwrap_or(&[]);
    // Copied to RAM: the LSTM reads its weights there, without the flash's wait states.
    let model_bytes = load_model_into_ram(MODEL_RAM.take(), blob);
    let app = APP.init_with(|| App::new(PROFILE, model_bytes));
    match app.model() {
        Ok(m) => info!(
            "{}",
            ModelLine {
                model: m,
                default_blob_len: DEFAULT_BLOB_LEN
            }
        ),
        Err(e) => error!("model fault {}: no flags, a fault frame every second", e),
    }

    // UNSTABLE line to the hand controller: high while the hand flag is up (status bit HAND_UNSTABLE).
    let mut unstable_pin = Output::new(p.PB12, Level::Low, Speed::VeryHigh);
    let mut led = Output::new(p.PC12, Level::Low, Speed::Low);

    // UART to the hand controller.
    let mut ucfg = usart::Config::default();
    ucfg.baudrate = BAUD;
    let uart = match Uart::new(p.USART1, p.PB7, p.PB6, p.DMA2_CH7, p.DMA2_CH2, Irqs, ucfg) {
        Ok(u) => u,
        Err(e) => {
            error!("USART1 config {}", e);
            loop {
                Timer::after_secs(1).await;
            }
        }
    };
    let (tx, rx) = uart.split();
    let rx = rx.into_ring_buffered(UART_RX_RING.init([0; 256]));
    spawner.spawn(rx_task(rx).expect("rx task spawned twice"));
    spawner.spawn(tx_task(tx).expect("tx task spawned twice"));

    // ADC1: timer-triggered scan of the profile's channels, DMA2 stream 0 into the ring.
    let rate_mhz = app.rate_mhz();
    let adc = Adc::new(p.ADC1);
    let st = SampleTime::CYCLES480;
    #[cfg(not(feature = "profile-suction"))]
    let seq = [
        (p.PA0.degrade_adc(), st),
        (p.PA1.degrade_adc(), st),
        (p.PA2.degrade_adc(), st),
        (p.PA3.degrade_adc(), st),
        (p.PA4.degrade_adc(), st),
        (p.PA5.degrade_adc(), st),
        (p.PA6.degrade_adc(), st),
        (p.PA7.degrade_adc(), st),
        (p.PB0.degrade_adc(), st),
        (p.PB1.degrade_adc(), st),
        (p.PC0.degrade_adc(), st),
        (p.PC1.degrade_adc(), st),
        (p.PC2.degrade_adc(), st),
        (p.PC3.degrade_adc(), st),
        (p.PC4.degrade_adc(), st),
        (p.PC5.degrade_adc(), st),
    ];
    #[cfg(feature = "profile-suction")]
    let seq = [
        (p.PA0.degrade_adc(), st),
        (p.PA1.degrade_adc(), st),
        (p.PA2.degrade_adc(), st),
        (p.PA3.degrade_adc(), st),
    ];
    let rb = adc.into_ring_buffered(
        p.DMA2_CH0,
        ADC_RING.init([0; 2 * HALF]),
        Irqs,
        seq.into_iter(),
        embassy_stm32::triggers::TIM2_TRGO,
        Exten::RISING_EDGE,
    );
    let _scan_timer = start_scan_timer(p.TIM2, rate_mhz);
    spawner.spawn(adc_task(rb, Frontend::new(PROFILE)).expect("adc task spawned twice"));

    // The inference task: commands and frames in arrival order.
    let deadline = Deadline::for_rate_mhz(rate_mhz);
    let stall_after = Duration::from_micros(3 * deadline.period_us as u64);
    let mut deframer = Deframer::new();
    let mut skipped_seen = 0u32;
    let mut last_fault = 0u16;
    let (mut cyc_min, mut cyc_max, mut cyc_sum, mut cyc_n) = (u32::MAX, 0u32, 0u64, 0u32);
    let report_every = (rate_mhz.0 / 100).max(1); // every 10 s
    loop {
        let ev = match with_timeout(stall_after, EVENTS.receive()).await {
            Ok(ev) => ev,
            Err(_) => {
                // No frame for three periods: the ADC or its DMA stopped. Report it; the
                // watchdog is not fed here, so the part resets if this lasts.
                error!("no ADC frame for 3 periods");
                let f = app.stall_frame(3);
                send(app, &f);
                continue;
            }
        };
        match ev {
            Event::Rx(bytes) => {
                let mut replies: heapless::Vec<Frame, 8> = heapless::Vec::new();
                let reload =
                    upload::receive(&mut uploader, app, &mut flash, &mut deframer, &bytes, |f| {
                        let _ = replies.push(*f);
                    });
                for f in &replies {
                    debug!("reply type {:#04x}", f.msg.msg_type());
                    send(app, f);
                }
                wdg.pet(); // a slot erase may have stalled the CPU for up to 2 s
                if let Some(a) = reload {
                    // Model changed: restart so that the boot path selects slot `a`, copies it
                    // and sets the ADC rate and deadlines from it. The reply goes out first;
                    // nothing else is handled meanwhile (`upload::receive` stopped at the
                    // commit, and this task waits), so flagging stays off: the commit was
                    // refused while armed, and no grasp start is handled before the reset.
                    info!(
                        "model uploaded into slot {} (sequence {}): restarting",
                        a.slot, a.seq
                    );
                    Timer::after_millis(20).await;
                    cortex_m::peripheral::SCB::sys_reset();
                }
            }
            Event::Frame(input, available_us) => {
                let skipped = SKIPPED.load(Ordering::Relaxed);
                while skipped_seen != skipped {
                    app.note_skipped();
                    skipped_seen = skipped_seen.wrapping_add(1);
                }
                let c0 = cortex_m::peripheral::DWT::cycle_count();
                let r = app.infer(&input);
                let cycles = cortex_m::peripheral::DWT::cycle_count().wrapping_sub(c0);
                let late = deadline.is_late(available_us, Instant::now().as_micros());
                if late {
                    warn!(
                        "frame {} late: {} cycles, overruns {}",
                        input.index,
                        cycles,
                        app.overruns().saturating_add(1)
                    );
                }
                if let Some(f) = app.emit_samples(&r, late) {
                    send(app, &f);
                }
                if let Some(f) = app.emit(&r, late) {
                    send(app, &f);
                }
                // The UNSTABLE line is the hand flag (status bit HAND_UNSTABLE of the frame).
                if r.hand_unstable {
                    unstable_pin.set_high();
                } else {
                    unstable_pin.set_low();
                }
                if input.fault != last_fault {
                    warn!(
                        "frame {}: sensor fault mask {:#06x} (kinds per channel, 1 open 2 saturated 4 stuck: {})",
                        input.index,
                        input.fault,
                        input.kinds[..CHANNELS]
                    );
                    last_fault = input.fault;
                }
                wdg.pet();
                led.toggle();
                cyc_min = cyc_min.min(cycles);
                cyc_max = cyc_max.max(cycles);
                cyc_sum += cycles as u64;
                cyc_n += 1;
                debug!("frame {}: {} cycles", input.index, cycles);
                if cyc_n >= report_every {
                    // The chip's figures beside the QEMU estimate (`scripts/qemu-bench.sh`,
                    // `cycles:` line): cycles per frame and per channel step, and the CPU share
                    // at this model rate (frames at rate_mhz / 1000 Hz on a `sysclk` core).
                    let mean = cyc_sum / cyc_n as u64;
                    let share_permille = mean * rate_mhz.0 as u64 / (sysclk as u64).max(1);
                    info!(
                        "inference cycles per frame ({} ch): min {} mean {} max {} ({} frames), {} per channel step, CPU {}.{} % at {} mHz; overruns {}, skipped {}",
                        CHANNELS,
                        cyc_min,
                        mean,
                        cyc_max,
                        cyc_n,
                        mean / CHANNELS as u64,
                        share_permille / 10,
                        share_permille % 10,
                        rate_mhz.0,
                        app.overruns(),
                        app.skipped()
                    );
                    (cyc_min, cyc_max, cyc_sum, cyc_n) = (u32::MAX, 0, 0, 0);
                }
            }
        }
    }
}
