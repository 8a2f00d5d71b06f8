//! The Cortex-M4F side: entry point, semihosting output, instruction counting with SysTick,
//! RAM report and stack painting, panic handler.
//!
//! Instruction counting: under `qemu-system-arm -icount shift=0` every instruction advances
//! virtual time by 1 ns, and SysTick (processor clock source, 25 MHz on mps2-an386) counts
//! virtual time, so one SysTick count is 40 instructions. The factor is not assumed: at start
//! the firmware runs `cortex_m::asm::delay(N)`, a `subs`/`bne` loop of exactly 2 (N + 1)
//! instructions, and derives instructions per count from it (printed as `calibration`).
//! QEMU 7.2 models no DWT cycle counter (CYCCNT reads stay 0), so SysTick is the clock.

use crate::app::{self, Platform, State};
use core::fmt::Write;
use core::sync::atomic::{compiler_fence, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hio};
use static_cell::ConstStaticCell;

/// All of the loop's state in static RAM (about 51 KiB; see the `ram_*` lines).
static STATE: ConstStaticCell<State> = ConstStaticCell::new(State::new());

/// Word the free stack is painted with.
const PAINT: u32 = 0xdead_beef;

extern "C" {
    static __sdata: u32;
    static __edata: u32;
    static __sbss: u32;
    static __ebss: u32;
    static _stack_start: u32;
}

fn addr(p: *const u32) -> usize {
    p as usize
}

struct Board {
    out: Option<hio::HostStream>,
    /// Owned so nothing else reconfigures the counter.
    _syst: SYST,
    last: u32,
    counts: u64,
    /// Instructions per SysTick count, as a ratio num / den.
    num: u64,
    den: u64,
}

impl Board {
    /// SysTick counts down from 2^24 - 1 and wraps; reading often enough (well under 2^24
    /// counts = 671 M instructions apart) extends it to 64 bits.
    fn counts(&mut self) -> u64 {
        let now = SYST::get_current();
        self.counts += (self.last.wrapping_sub(now) & 0x00ff_ffff) as u64;
        self.last = now;
        self.counts
    }
}

impl Platform for Board {
    fn line(&mut self, args: core::fmt::Arguments<'_>) {
        if let Some(o) = self.out.as_mut() {
            let _ = o.write_fmt(args);
            let _ = o.write_str("\n");
        }
    }
    fn instructions(&mut self) -> u64 {
        // Fences keep the compiler from moving the measured work across the counter reads
        // (volatile accesses only order other volatile accesses).
        compiler_fence(Ordering::SeqCst);
        let c = self.counts();
        compiler_fence(Ordering::SeqCst);
        c * self.num / self.den
    }
}

/// Paints the free stack below the current stack pointer (minus a margin for this frame).
#[inline(never)]
fn paint_stack() {
    let sp = cortex_m::register::msp::read() as usize;
    let bottom = addr(&raw const __ebss);
    let mut p = (bottom + 3) & !3;
    while p + 256 < sp {
        // SAFETY: [__ebss, sp - 256) is RAM that nothing uses yet: above the statics, below
        // the live stack frames; writes are aligned words.
        unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// Bytes of stack ever used: from the top of RAM down to the lowest overwritten paint word.
fn stack_used() -> usize {
    let top = addr(&raw const _stack_start);
    let mut p = (addr(&raw const __ebss) + 3) & !3;
    // SAFETY: reads aligned words of RAM between the statics and the stack top.
    while p < top && unsafe { core::ptr::read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    top - p
}

#[entry]
fn main() -> ! {
    paint_stack();
    // Taken once, at reset: cannot be gone already.
    let Some(mut cp) = cortex_m::Peripherals::take() else {
        panic!("core peripherals taken twice");
    };
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(0x00ff_ffff);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();
    let mut b = Board {
        out: hio::hstdout().ok(),
        _syst: cp.SYST,
        last: SYST::get_current(),
        counts: 0,
        num: 1,
        den: 1,
    };
    // Calibration: delay(N) executes 2 (N + 1) instructions.
    const N: u32 = 500_000;
    let c0 = b.counts();
    cortex_m::asm::delay(N);
    let c1 = b.counts();
    b.num = 2 * (N as u64 + 1);
    b.den = (c1 - c0).max(1);
    let (num, den) = (b.num, b.den);
    b.line(format_args!(
        "calibration delay_instructions={} systick_counts={} instructions_per_count={}",
        num,
        den,
        num / den
    ));
    let state = STATE.take();
    let ok = app::run(&mut b, state);
    let data = addr(&raw const __edata) - addr(&raw const __sdata);
    let bss = addr(&raw const __ebss) - addr(&raw const __sbss);
    let stack = stack_used();
    b.line(format_args!(
        "ram_data={} ram_bss={} stack_used={} ram_total={} ram_limit=65536",
        data,
        bss,
        stack,
        data + bss + stack
    ));
    debug::exit(if ok {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    // Only reached without a debugger/QEMU to exit to: sleep.
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    if let Ok(mut o) = hio::hstdout() {
        let _ = writeln!(o, "panic: {info}");
    }
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
