//! Text output: the report lines of `nemm_firmware::report`.
//!
//! - On the board: SEGGER RTT, up channel 0 ("Terminal"), which `probe-rs run` (and
//!   `probe-rs attach`) prints as the target runs. The control block `_SEGGER_RTT` is a
//!   symbol of the image, so the probe finds it without scanning RAM. A line that does not
//!   fit the channel's free space is dropped whole (nothing waits for the host) and counted
//!   ([`Console::dropped`]); without a probe attached the buffer just fills.
//! - Under the `qemu` feature: semihosting stdout, which QEMU prints.

#[cfg(not(feature = "qemu"))]
mod rtt {
    use core::cell::UnsafeCell;
    use core::sync::atomic::{compiler_fence, AtomicU32, Ordering};

    /// Bytes of the up channel's ring buffer (one stays free).
    pub const BUFFER_LEN: usize = 2048;

    /// One RTT channel descriptor (`SEGGER_RTT_BUFFER_UP`).
    #[repr(C)]
    struct Channel {
        name: *const u8,
        buffer: *mut u8,
        size: u32,
        write: AtomicU32,
        read: AtomicU32,
        flags: u32,
    }

    /// The RTT control block (`SEGGER_RTT_CB`): one up channel, no down channel.
    #[repr(C)]
    pub struct ControlBlock {
        id: UnsafeCell<[u8; 16]>,
        max_up: u32,
        max_down: u32,
        up: Channel,
    }

    /// The ring buffer, written by the target, read by the probe.
    struct Buffer(UnsafeCell<[u8; BUFFER_LEN]>);

    // SAFETY: one writer (the console, owned by `idle`) and the probe, which only reads the
    // bytes between `read` and `write`; the offsets are atomics.
    unsafe impl Sync for Buffer {}
    // SAFETY: as for `Buffer`; the id is written once at start-up, before anything reads it.
    unsafe impl Sync for ControlBlock {}

    static BUFFER: Buffer = Buffer(UnsafeCell::new([0; BUFFER_LEN]));

    /// The control block the probe looks for (by symbol, then by its id).
    #[no_mangle]
    #[used]
    pub static _SEGGER_RTT: ControlBlock = ControlBlock {
        // Written at start-up ([`start`]): a stale block left in RAM by an earlier image
        // does not look valid before this one is set up.
        id: UnsafeCell::new([0; 16]),
        max_up: 1,
        max_down: 0,
        up: Channel {
            name: c"Terminal".as_ptr().cast(),
            buffer: BUFFER.0.get().cast(),
            size: BUFFER_LEN as u32,
            write: AtomicU32::new(0),
            read: AtomicU32::new(0),
            // SEGGER_RTT_MODE_NO_BLOCK_SKIP.
            flags: 0,
        },
    };

    /// Marks the control block valid.
    pub fn start() {
        compiler_fence(Ordering::SeqCst);
        // SAFETY: the id is only written here, once, before the first `write`.
        unsafe {
            core::ptr::write_volatile(_SEGGER_RTT.id.get(), *b"SEGGER RTT\0\0\0\0\0\0");
        }
        compiler_fence(Ordering::SeqCst);
    }

    /// Appends `bytes` to the ring if they fit whole; `false` if not.
    pub fn write(bytes: &[u8]) -> bool {
        let ch = &_SEGGER_RTT.up;
        let w = ch.write.load(Ordering::Relaxed) as usize % BUFFER_LEN;
        let r = ch.read.load(Ordering::Acquire) as usize % BUFFER_LEN;
        let free = if r > w {
            r - w - 1
        } else {
            BUFFER_LEN - 1 - w + r
        };
        if bytes.len() > free {
            return false;
        }
        let base: *mut u8 = BUFFER.0.get().cast();
        let mut at = w;
        for &b in bytes {
            // SAFETY: `at < BUFFER_LEN`; the bytes from `write` up to `read` are the writer's.
            unsafe { core::ptr::write_volatile(base.add(at), b) };
            at = if at + 1 == BUFFER_LEN { 0 } else { at + 1 };
        }
        ch.write.store(at as u32, Ordering::Release);
        true
    }
}

/// The console of this build (RTT on the board, semihosting under QEMU).
pub struct Console {
    #[cfg(feature = "qemu")]
    out: Option<cortex_m_semihosting::hio::HostStream>,
    dropped: u32,
}

impl Console {
    /// Opens the console (once, in `init`).
    pub fn open() -> Self {
        #[cfg(not(feature = "qemu"))]
        rtt::start();
        Self {
            #[cfg(feature = "qemu")]
            out: cortex_m_semihosting::hio::hstdout().ok(),
            dropped: 0,
        }
    }

    /// Writes one line (dropped whole if RTT has no room).
    pub fn write(&mut self, bytes: &[u8]) {
        #[cfg(not(feature = "qemu"))]
        if !rtt::write(bytes) {
            self.dropped = self.dropped.wrapping_add(1);
        }
        #[cfg(feature = "qemu")]
        if let Some(out) = &mut self.out {
            if out.write_all(bytes).is_err() {
                self.dropped = self.dropped.wrapping_add(1);
            }
        }
    }

    /// Lines dropped so far.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }
}
