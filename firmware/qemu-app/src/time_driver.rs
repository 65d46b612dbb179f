//! embassy-time driver on SysTick for QEMU mps2-an386 (25 MHz core clock): SysTick interrupts
//! every millisecond and extends itself to a 64-bit cycle count; `now()` is in µs (embassy-time
//! feature `tick-hz-1_000_000`); alarms live in embassy's timer queue and are checked every
//! millisecond. Under `-icount shift=0` one core cycle is exactly 40 executed instructions, so
//! [`cycles`] doubles as an instruction counter with 40-instruction resolution.

use core::cell::{Cell, RefCell};
use core::task::Waker;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use cortex_m_rt::exception;
use critical_section::Mutex;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

/// mps2-an386 core clock.
pub const CORE_HZ: u32 = 25_000_000;
/// Executed instructions per core cycle under `-icount shift=0` (1 ns per instruction).
pub const INSNS_PER_CYCLE: u64 = 40;
const CYCLES_PER_MS: u32 = CORE_HZ / 1000;

struct SysTickDriver {
    /// Whole milliseconds elapsed (SysTick wraps handled).
    millis: Mutex<Cell<u64>>,
    /// Next alarm, µs.
    alarm: Mutex<Cell<u64>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    millis: Mutex::new(Cell::new(0)),
    alarm: Mutex::new(Cell::new(u64::MAX)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// Starts SysTick: core clock, 1 ms period, interrupt on.
pub fn init(mut syst: SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(CYCLES_PER_MS - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

fn cycles_cs(cs: critical_section::CriticalSection<'_>) -> u64 {
    let mut ms = DRIVER.millis.borrow(cs).get();
    let mut cvr = SYST::get_current();
    // A wrap whose interrupt is still pending (we are in a critical section): count it.
    if SCB::is_pendst_pending() {
        ms += 1;
        cvr = SYST::get_current();
    }
    ms * CYCLES_PER_MS as u64 + (CYCLES_PER_MS - 1 - cvr) as u64
}

/// Core cycles since [`init`] (× [`INSNS_PER_CYCLE`] = executed instructions under icount).
pub fn cycles() -> u64 {
    critical_section::with(cycles_cs)
}

impl Driver for SysTickDriver {
    fn now(&self) -> u64 {
        cycles() / (CORE_HZ as u64 / 1_000_000)
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let mut q = self.queue.borrow(cs).borrow_mut();
            if q.schedule_wake(at, waker) {
                let now = cycles_cs(cs) / (CORE_HZ as u64 / 1_000_000);
                self.alarm.borrow(cs).set(q.next_expiration(now));
            }
        });
    }
}

#[exception]
fn SysTick() {
    critical_section::with(|cs| {
        let ms = DRIVER.millis.borrow(cs);
        ms.set(ms.get() + 1);
        let now = ms.get() * 1000;
        let alarm = DRIVER.alarm.borrow(cs);
        if now >= alarm.get() {
            let next = DRIVER.queue.borrow(cs).borrow_mut().next_expiration(now);
            alarm.set(next);
        }
    });
}
