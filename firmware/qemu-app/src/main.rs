//! The slipguard firmware application on QEMU `-M mps2-an386` (Cortex-M4F).
//!
//! Only the board layer differs from `firmware/src`: instead of ADC1 + DMA, [`adc_task`] replays
//! the recorded trial compiled in (`slipguard_app::replay::CHEEZ_TRIAL`, eagle-shoal
//! Cheez_100_814_top_3, CDLA-Permissive-1.0) through the emulated sensor, one scan at a time,
//! and delivers the command script's bytes as the UART would; instead of the UART, frames go to
//! the host file `qemu-frames.bin` (semihosting). The pipeline, the task structure (one event
//! queue feeding the inference task, commands and frames in arrival order), the deadline check
//! and the model blob in its own `.model` section read back through the region's address are the
//! firmware's. `scripts/qemu-replay.sh` compares the file with the host replay byte for byte.
//!
//! With the `field` feature the command script is `slipguard_app::replay::field_script` (sample
//! stream, phase commands, an upload of a second model into a RAM-backed flash slot), compared
//! with `replay_field`, the host side. The profile, the trial and the uploaded blob then come
//! from a scenario (`slipguard_app::replay::scenario`) that QEMU loads into the SCENARIO region
//! (`memory.x`) when there is one, else the compiled-in Cheez trial and golden test model on
//! the hand profile.
//!
//! Stdout (semihosting) gets a text log and the instruction counts per frame; exit status 0 when
//! the run completed, 101 on a panic (`slipguard_support::semihosting`).
#![no_std]
#![no_main]

mod time_driver;

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m_semihosting::{hprintln, nr, syscall};
use embassy_executor::Spawner;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_time::Instant;
use slipguard_app::app::App;
use slipguard_app::decimate::RATIO;
use slipguard_app::frontend::{FrameInput, Frontend};
use slipguard_app::profile::{AdcCode, Profile};
use slipguard_app::replay::scenario::Scenario;
use slipguard_app::replay::{self, CHEEZ_TRIAL, EmulatedSensor};
use slipguard_app::schedule::Deadline;
use slipguard_app::upload::{self, SimFlash, Uploader};
use slipguard_core::model_ram::ModelRam;
use slipguard_core::protocol::{Deframer, Frame, MAX_WIRE};
use slipguard_support::boot::ModelLine;
use slipguard_support::semihosting::exit;
use static_cell::{ConstStaticCell, StaticCell};

/// The sensor profile of the compiled-in scenario.
const PROFILE: Profile = Profile::HAND;

// The MODEL region (default blob in the `.model` section, replaceable at load time).
use slipguard_support::model::{DEFAULT_BLOB_LEN, region as model_region};

/// What the inference task receives, in arrival order.
enum Event {
    /// Bytes from the (emulated) UART.
    Rx(heapless::Vec<u8, 32>),
    /// One frame's input and when it became available (µs).
    Frame(FrameInput, u64),
    /// The recorded trial is over.
    End,
}

static EVENTS: Channel<CriticalSectionRawMutex, Event, 4> = Channel::new();
static APP: StaticCell<App<'static>> = StaticCell::new();
/// The two model slots in RAM (128 KiB each, as the F405's sectors 10 and 11).
static SLOT0: StaticCell<[u32; 128 * 1024 / 4]> = StaticCell::new();
static SLOT1: StaticCell<[u32; 128 * 1024 / 4]> = StaticCell::new();

#[cfg(feature = "field")]
#[repr(C, align(4))]
struct Aligned<T>(T);

/// The blob the field script uploads (the golden test model), 4-byte aligned as a blob must be.
#[cfg(feature = "field")]
static SECOND: Aligned<[u8; SECOND_LEN]> =
    Aligned(*include_bytes!("../../core/tests/fixtures/bench/model.bin"));
#[cfg(feature = "field")]
const SECOND_LEN: usize = include_bytes!("../../core/tests/fixtures/bench/model.bin").len();

/// The compiled-in scenario: the Cheez trial on the hand profile (with `field`, uploading the
/// golden test model).
const COMPILED_IN: Scenario<'static> = Scenario {
    profile: PROFILE,
    trial: CHEEZ_TRIAL,
    #[cfg(feature = "field")]
    upload: &SECOND.0,
    #[cfg(not(feature = "field"))]
    upload: &[],
};

#[cfg(feature = "field")]
unsafe extern "C" {
    static __sscenario: u8;
    static __escenario: u8;
}

/// The run's scenario: with `field`, the one loaded into the SCENARIO region if its magic is
/// there (a bad one stops the run with exit status 2), else the compiled-in one.
fn scenario() -> Scenario<'static> {
    #[cfg(feature = "field")]
    {
        let start = &raw const __sscenario;
        let end = &raw const __escenario;
        let len = (end as usize).saturating_sub(start as usize);
        // SAFETY: `memory.x` defines both symbols as the bounds of the SCENARIO region, RAM
        // that nothing is linked into and nothing writes during the run (QEMU's loader fills
        // it before the CPU starts), readable for the whole run.
        let region = unsafe { core::slice::from_raw_parts(start, len) };
        match replay::scenario::parse(region) {
            Ok(s) => {
                hprintln!(
                    "slipguard-qemu-app: scenario from 0x{:08x}: {} profile, {} steps, {}-byte blob to upload",
                    start as usize,
                    s.profile.name,
                    s.trial.steps(),
                    s.upload.len()
                );
                return s;
            }
            Err(replay::scenario::ScenarioError::NoMagic) => {}
            Err(e) => {
                hprintln!("slipguard-qemu-app: {}", e);
                exit(2)
            }
        }
    }
    COMPILED_IN
}

/// The command bytes scheduled before frame `index` (`upload`: the blob the field script sends).
fn script_bytes(index: u32, upload: &[u8], out: &mut heapless::Vec<u8, 2048>) {
    #[cfg(feature = "field")]
    replay::field_script::commands(index, upload, |b| {
        let _ = out.extend_from_slice(b);
    });
    #[cfg(not(feature = "field"))]
    let _ = upload;
    #[cfg(not(feature = "field"))]
    for item in replay::cheez_script::SCRIPT
        .iter()
        .filter(|s| s.before_frame == index)
    {
        let _ = out.extend_from_slice(item.bytes);
    }
}
/// The model's RAM image, as on the board (`firmware/src/main.rs`).
static MODEL_RAM: ConstStaticCell<ModelRam> = ConstStaticCell::new(ModelRam::new());
/// Span of the cycle plugin (`firmware/qemu-bench/plugin`) around `App::infer`: a store to
/// 0x2030_0000 + 8·1 opens it, + 4 closes it (RAM nothing else uses).
const INFER_SPAN_OPEN: usize = 0x2030_0008;
const INFER_SPAN_CLOSE: usize = 0x2030_000C;
/// Frames the ADC side could not queue (none here: the emulation waits instead).
static SKIPPED: AtomicU32 = AtomicU32::new(0);

/// Host file for the frames (semihosting SYS_OPEN / SYS_WRITE).
struct HostFile(usize);

impl HostFile {
    fn create(name: &str) -> Option<Self> {
        let mut path = [0u8; 64];
        let n = name.len().min(63);
        path[..n].copy_from_slice(&name.as_bytes()[..n]);
        // SAFETY: a semihosting call with a NUL-terminated path, a mode and the path length.
        let fd = unsafe { syscall!(OPEN, path.as_ptr(), nr::open::W_TRUNC_BINARY, n) } as isize;
        (fd >= 0).then_some(Self(fd as usize))
    }
    fn write(&mut self, bytes: &[u8]) {
        // SAFETY: semihosting write of a valid buffer to an fd the host opened.
        unsafe { syscall!(WRITE, self.0, bytes.as_ptr(), bytes.len()) };
    }
    fn frame(&mut self, f: &Frame) {
        let mut buf = [0u8; MAX_WIRE];
        let n = replay::wire(f, &mut buf);
        self.write(&buf[..n]);
    }
}

/// Board layer, sampling side: the recorded trial through the emulated sensor, scan by scan,
/// into the same front end the firmware's ADC task runs; the command script's bytes arrive just
/// before the frame they are scheduled for.
#[embassy_executor::task]
async fn adc_task(run: Scenario<'static>) {
    let profile = run.profile;
    let mut frontend = Frontend::new(profile);
    #[cfg(not(feature = "field"))]
    let mut sensor = EmulatedSensor::with_open_wires(profile, replay::cheez_script::OPEN_WIRES);
    #[cfg(feature = "field")]
    let mut sensor = EmulatedSensor::new(profile);
    let mut scan = [AdcCode(0); 16];
    for step in 0..run.trial.steps() {
        for _ in 0..RATIO {
            sensor.scan(&run.trial, step, &mut scan);
            let Some(input) = frontend.push_scan(&scan) else {
                continue;
            };
            let mut bytes = heapless::Vec::new();
            script_bytes(input.index, run.upload, &mut bytes);
            for chunk in bytes.chunks(32) {
                let v = heapless::Vec::from_slice(chunk).unwrap_or_default();
                EVENTS.send(Event::Rx(v)).await;
            }
            EVENTS
                .send(Event::Frame(input, Instant::now().as_micros()))
                .await;
        }
        // One DMA half-buffer per step on the board: let the executor run.
        embassy_futures::yield_now().await;
    }
    EVENTS.send(Event::End).await;
}

/// Instruction statistics of `App::infer` over frames without a sensor fault: with feature
/// `all-contact` every channel is predicted in them, else only the channels in contact.
#[derive(Default)]
struct Stats {
    n: u64,
    sum: u64,
    min: u64,
    max: u64,
}

impl Stats {
    fn add(&mut self, insns: u64) {
        if self.n == 0 || insns < self.min {
            self.min = insns;
        }
        self.max = self.max.max(insns);
        self.sum += insns;
        self.n += 1;
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let cp = cortex_m::Peripherals::take().expect("core peripherals taken twice");
    time_driver::init(cp.SYST);
    let run = scenario();
    let profile = run.profile;
    // RAM-backed model slots: the image's model in the factory slot, the other one erased.
    let slot0 = SLOT0.init([u32::MAX; 128 * 1024 / 4]);
    let slot1 = SLOT1.init([u32::MAX; 128 * 1024 / 4]);
    for (w, b) in slot1.iter_mut().zip(model_region().chunks_exact(4)) {
        *w = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    }
    let mut flash = SimFlash::new(slot0, slot1);
    let mut uploader = Uploader::new(upload::select(&flash, &profile));
    // As on the board (the factory slot's blob): the blob validated and copied to RAM, or run in place if it is bad.
    let (model_bytes, copied) = upload::load(MODEL_RAM.take(), model_region());
    if let Err(e) = copied {
        hprintln!("slipguard-qemu-app: model stays in flash: {}", e);
    }
    let app = APP.init_with(|| App::new(profile, model_bytes));
    #[cfg(feature = "all-contact")]
    {
        // |x| ≥ 0 always holds: every channel is in contact from frame 0 and never leaves.
        app.set_contact_config(slipguard_core::decision::ContactConfig {
            on_q15: 0,
            on_after: 1,
            off_after: 1,
        });
        hprintln!("slipguard-qemu-app: every channel in contact (feature all-contact)");
    }
    match app.model() {
        Ok(m) => hprintln!(
            "slipguard-qemu-app: {}",
            ModelLine {
                model: m,
                default_blob_len: DEFAULT_BLOB_LEN
            }
        ),
        Err(e) => hprintln!(
            "slipguard-qemu-app: MODEL FAULT {:?}: no flags, fault frames only",
            e
        ),
    }
    let Some(mut out) = HostFile::create("qemu-frames.bin") else {
        hprintln!("cannot create qemu-frames.bin on the host");
        exit(2)
    };
    spawner.spawn(adc_task(run).expect("adc task spawned twice"));

    let deadline = Deadline::for_rate_mhz(app.rate_mhz());
    let mut deframer = Deframer::new();
    let mut stats = Stats::default();
    let mut frames = 0u32;
    let mut skipped_seen = 0;
    loop {
        match EVENTS.receive().await {
            Event::Rx(bytes) => {
                let reload =
                    upload::receive(&mut uploader, app, &mut flash, &mut deframer, &bytes, |f| {
                        out.frame(f);
                        frames += 1;
                    });
                if let Some(a) = reload {
                    hprintln!(
                        "slipguard-qemu-app: new model in slot {} (sequence {})",
                        a.slot,
                        a.seq
                    );
                    // The firmware restarts here; the emulation reloads in place from the RAM
                    // copy of what was sent, as `replay::run_field` does.
                    #[cfg(feature = "field")]
                    {
                        let same = upload::blob(&flash, Some(a)) == run.upload;
                        app.reload_in_place(if same { run.upload } else { &[] });
                    }
                }
            }
            Event::Frame(input, available_us) => {
                let skipped = SKIPPED.load(Ordering::Relaxed);
                while skipped_seen != skipped {
                    app.note_skipped();
                    skipped_seen += 1;
                }
                let counted = input.fault == 0 && app.model().is_ok();
                if counted {
                    // SAFETY: an address in RAM that nothing else uses; the plugin watches it.
                    unsafe { core::ptr::write_volatile(INFER_SPAN_OPEN as *mut u32, 1) };
                }
                let c0 = time_driver::cycles();
                let r = app.infer(&input);
                let c1 = time_driver::cycles();
                if counted {
                    // SAFETY: as above.
                    unsafe { core::ptr::write_volatile(INFER_SPAN_CLOSE as *mut u32, 1) };
                }
                let late = deadline.is_late(available_us, Instant::now().as_micros());
                if let Some(f) = app.emit_samples(&r, late) {
                    out.frame(&f);
                    frames += 1;
                }
                if let Some(f) = app.emit(&r, late) {
                    out.frame(&f);
                    frames += 1;
                }
                if counted {
                    stats.add((c1 - c0) * time_driver::INSNS_PER_CYCLE);
                }
            }
            Event::End => break,
        }
    }
    hprintln!(
        "slipguard-qemu-app: {} frames written, {} overruns, {} skipped",
        frames,
        app.overruns(),
        app.skipped()
    );
    if let Some(mean) = stats.sum.checked_div(stats.n) {
        hprintln!(
            "insns per {}-channel frame (App::infer): mean {} min {} max {} over {} frames (±40)",
            profile.channels,
            mean,
            stats.min,
            stats.max,
            stats.n
        );
    }
    exit(0)
}
