//! Running the firmware in QEMU (`qemu-system-arm -machine mps2-an386`, or the machine
//! `NEMM_QEMU_MACHINE` names) and parsing what it prints (the line format of
//! `nemm_firmware::report`).
//!
//! The firmware images come from `cargo xtask test`, which builds each configuration once and
//! passes the paths in the environment:
//!
//! | variable | image |
//! |----------|-------|
//! | `NEMM_FIRMWARE_ELF` | the application, release, `qemu` feature |
//! | `NEMM_FIRMWARE_RELEASE_ELF` | the application as flashed to a board (release, no `qemu`) |
//! | `NEMM_BENCH_ELF` | the step benchmark, release, `qemu` feature |
//! | `NEMM_BOARD_ELF` | the STM32F407 image as flashed (`boards/nemm-stm32f407`) |
//! | `NEMM_BOARD_QEMU_ELF` | the STM32F407 image with its `qemu` feature (netduinoplus2) |
//! | `NEMM_QEMU` | `qemu-system-arm` to use (default: from `PATH`) |
//! | `NEMM_QEMU_MACHINE`, `NEMM_QEMU_CPU` | the board of the images (default `mps2-an386`, `cortex-m4`; `cargo xtask test` runs the tests again with `mps2-an500`, `cortex-m7`) |
//!
//! The QEMU tests are `#[ignore]`d, so that a plain `cargo test` reports them as not run;
//! `cargo xtask test` runs them (`--ignored`) with these variables set. Run without them,
//! they fail and say what is missing.

use crate::elf::Elf;
use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The firmware images of one build.
#[derive(Debug, Clone)]
pub struct Images {
    /// The application with the `qemu` feature.
    pub app: PathBuf,
    /// The application without it (what a board runs).
    pub app_release: PathBuf,
    /// The step benchmark.
    pub bench: PathBuf,
    /// The emulator.
    pub qemu: PathBuf,
}

impl Images {
    /// The images named in the environment; panics with what is missing and how to run the
    /// QEMU tests if they are not set.
    pub fn from_env() -> Self {
        let var = |k: &str| std::env::var_os(k).map(PathBuf::from);
        let missing: Vec<&str> = [
            "NEMM_FIRMWARE_ELF",
            "NEMM_FIRMWARE_RELEASE_ELF",
            "NEMM_BENCH_ELF",
        ]
        .into_iter()
        .filter(|k| std::env::var_os(k).is_none())
        .collect();
        match (
            var("NEMM_FIRMWARE_ELF"),
            var("NEMM_FIRMWARE_RELEASE_ELF"),
            var("NEMM_BENCH_ELF"),
        ) {
            (Some(app), Some(app_release), Some(bench)) => Self {
                app,
                app_release,
                bench,
                qemu: var("NEMM_QEMU").unwrap_or_else(|| "qemu-system-arm".into()),
            },
            _ => panic!(
                "the QEMU tests need the firmware images, and {} not set: run them with \
                 `cargo xtask test`, which builds the firmware and sets them",
                if missing.len() == 1 {
                    format!("{} is", missing[0])
                } else {
                    format!("{} are", missing.join(", "))
                }
            ),
        }
    }
}

/// The STM32F407 images (`boards/nemm-stm32f407`), from `cargo xtask test`:
/// `NEMM_BOARD_ELF` (as flashed) and `NEMM_BOARD_QEMU_ELF` (`qemu` feature, for
/// netduinoplus2).
#[derive(Debug, Clone)]
pub struct BoardImages {
    /// The image as flashed to a board.
    pub board: PathBuf,
    /// The image for QEMU's netduinoplus2.
    pub qemu_image: PathBuf,
    /// The emulator.
    pub qemu: PathBuf,
}

impl BoardImages {
    /// The images named in the environment; panics with how to get them if not set.
    pub fn from_env() -> Self {
        let var = |k: &str| std::env::var_os(k).map(PathBuf::from);
        match (var("NEMM_BOARD_ELF"), var("NEMM_BOARD_QEMU_ELF")) {
            (Some(board), Some(qemu_image)) => Self {
                board,
                qemu_image,
                qemu: var("NEMM_QEMU").unwrap_or_else(|| "qemu-system-arm".into()),
            },
            _ => panic!(
                "the board tests need NEMM_BOARD_ELF and NEMM_BOARD_QEMU_ELF: run them with \
                 `cargo xtask test`, which builds boards/nemm-stm32f407 and sets them"
            ),
        }
    }
}

/// What one QEMU run printed and how it ended.
#[derive(Debug, Clone)]
pub struct Run {
    /// Exit status of QEMU (the firmware's semihosting exit code); `None` if killed.
    pub code: Option<i32>,
    /// Everything the firmware printed.
    pub stdout: String,
    /// QEMU's own messages.
    pub stderr: String,
    /// Wall-clock time of the run.
    pub wall: Duration,
}

impl Run {
    /// The parsed output.
    pub fn output(&self) -> Output {
        Output::parse(&self.stdout)
    }

    /// A summary for assertion messages: exit code, stderr and the output's last lines.
    pub fn describe(&self) -> String {
        let lines: Vec<&str> = self.stdout.lines().collect();
        let tail = lines[lines.len().saturating_sub(8)..].join("\n");
        format!(
            "exit {:?} after {:.1} s\n--- stderr\n{}\n--- last lines of stdout\n{tail}",
            self.code,
            self.wall.as_secs_f64(),
            self.stderr.trim_end()
        )
    }
}

/// Runs `elf` in QEMU on the board of [`board`] with the instruction counter on (`-icount
/// shift=0`: one instruction per emulated nanosecond, idle time skipped) and the firmware
/// options `args`; kills it after `timeout`.
pub fn run_qemu(qemu: &Path, elf: &Path, args: &[&str], timeout: Duration) -> Run {
    let mut semihosting = String::from("enable=on,target=native,arg=nemm-firmware");
    for a in args {
        assert!(!a.contains(','), "option {a:?} contains a comma");
        semihosting += &format!(",arg={a}");
    }
    let (cpu, machine) = board();
    run_machine(
        qemu,
        &["-cpu", &cpu, "-machine", &machine],
        elf,
        &semihosting,
        timeout,
    )
}

/// The QEMU CPU and machine of the images under test: `NEMM_QEMU_CPU` and
/// `NEMM_QEMU_MACHINE`, default `cortex-m4` on `mps2-an386`.
pub fn board() -> (String, String) {
    let var = |k: &str, default: &str| {
        std::env::var(k)
            .ok()
            .filter(|v| !v.is_empty())
            .unwrap_or_else(|| default.to_string())
    };
    (
        var("NEMM_QEMU_CPU", "cortex-m4"),
        var("NEMM_QEMU_MACHINE", "mps2-an386"),
    )
}

/// Runs `elf` on the QEMU machine `machine` (e.g. `["-machine", "netduinoplus2"]`) with the
/// instruction counter on, no monitor or serial port, and semihosting configured by
/// `semihosting`; kills it after `timeout`.
pub fn run_machine(
    qemu: &Path,
    machine: &[&str],
    elf: &Path,
    semihosting: &str,
    timeout: Duration,
) -> Run {
    let start = Instant::now();
    let mut child = Command::new(qemu)
        .args(machine)
        .args(["-nographic", "-monitor", "none", "-serial", "none"])
        .args(["-icount", "shift=0,sleep=off"])
        .args(["-semihosting-config", semihosting])
        .arg("-kernel")
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", qemu.display()));
    let reader = |mut r: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut b = Vec::new();
            let _ = r.read_to_end(&mut b);
            String::from_utf8_lossy(&b).into_owned()
        })
    };
    let out = reader(Box::new(child.stdout.take().expect("piped")));
    let err = reader(Box::new(child.stderr.take().expect("piped")));
    let code = loop {
        if let Some(status) = child.try_wait().expect("wait for qemu") {
            break status.code();
        }
        if start.elapsed() > timeout {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    Run {
        code,
        stdout: out.join().unwrap_or_default(),
        stderr: err.join().unwrap_or_default(),
        wall: start.elapsed(),
    }
}

/// `key=value` fields of one line.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Fields(pub BTreeMap<String, String>);

impl Fields {
    /// The raw value of `key`.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.0.get(key).map(String::as_str)
    }

    /// A decimal or `0x` hex value; panics with the key if absent or malformed.
    pub fn num(&self, key: &str) -> u32 {
        let v = self
            .get(key)
            .unwrap_or_else(|| panic!("no field `{key}` in {:?}", self.0));
        match v.strip_prefix("0x") {
            Some(h) => u32::from_str_radix(h, 16),
            None => v.parse(),
        }
        .unwrap_or_else(|e| panic!("field `{key}={v}`: {e}"))
    }
}

/// One `s` line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepLine {
    /// Sample index.
    pub k: u32,
    /// Bits of the velocity handed to the estimator.
    pub velocity_bits: u32,
    /// Bits of the force estimate.
    pub force_bits: u32,
    /// Estimator flags.
    pub estimator_flags: u8,
    /// Firmware flags.
    pub firmware_flags: u8,
    /// SysTick ticks of the step (0 on overrun).
    pub ticks: u32,
    /// The observer's part (bench-controller mode: `measured=`, `alpha=`, `band=`,
    /// `flags=`).
    pub observer: Option<ObserverPart>,
}

impl StepLine {
    /// The force estimate.
    pub fn force(&self) -> f32 {
        f32::from_bits(self.force_bits)
    }
}

/// The observer's fields of an `s` line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ObserverPart {
    /// Bits of the load cell's force handed to the observer.
    pub measured_bits: u32,
    /// Bits of the estimate of alpha.
    pub alpha_bits: u32,
    /// Bits of its band.
    pub band_bits: u32,
    /// The observer's flags.
    pub flags: u8,
}

impl ObserverPart {
    /// The estimate of alpha.
    pub fn alpha(&self) -> f32 {
        f32::from_bits(self.alpha_bits)
    }

    /// Its band.
    pub fn band(&self) -> f32 {
        f32::from_bits(self.band_bits)
    }
}

/// One `digest` line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DigestLine {
    /// Chunk index.
    pub chunk: u32,
    /// First sample of the chunk.
    pub first: u32,
    /// Periods in the chunk.
    pub steps: u32,
    /// CRC-32 of the chunk.
    pub crc: u32,
}

/// The parsed output of one run.
#[derive(Debug, Clone, Default)]
pub struct Output {
    /// Every line as printed.
    pub lines: Vec<String>,
    /// Lines other than `s` and `digest`, by tag (`boot`, `weights ok`, `weights-error`,
    /// `start`, `summary`, `exit`, `error`, ...); a repeated tag keeps the last.
    pub tagged: BTreeMap<String, Fields>,
    /// The `s` lines.
    pub steps: Vec<StepLine>,
    /// The `digest` lines.
    pub digests: Vec<DigestLine>,
}

impl Output {
    /// Parses the firmware's stdout; malformed `s` or `digest` lines panic.
    pub fn parse(text: &str) -> Self {
        let mut o = Output::default();
        for line in text.lines() {
            o.lines.push(line.to_string());
            if let Some(rest) = line.strip_prefix("s ") {
                let f: Vec<&str> = rest.split_ascii_whitespace().collect();
                let hex = |i: usize| {
                    u32::from_str_radix(f.get(i).copied().unwrap_or(""), 16)
                        .unwrap_or_else(|e| panic!("bad step line {line:?}: {e}"))
                };
                let dec = |i: usize| {
                    f.get(i)
                        .and_then(|v| v.parse::<u32>().ok())
                        .unwrap_or_else(|| panic!("bad step line {line:?}"))
                };
                let observer = match f.len() {
                    6 => None,
                    10 => {
                        let mut kv = Fields::default();
                        for w in &f[6..] {
                            let (k, v) = w
                                .split_once('=')
                                .unwrap_or_else(|| panic!("bad step line {line:?}"));
                            kv.0.insert(k.to_string(), v.to_string());
                        }
                        Some(ObserverPart {
                            measured_bits: kv.num("measured"),
                            alpha_bits: kv.num("alpha"),
                            band_bits: kv.num("band"),
                            flags: u8::try_from(kv.num("flags"))
                                .unwrap_or_else(|_| panic!("bad step line {line:?}")),
                        })
                    }
                    _ => panic!("bad step line {line:?}"),
                };
                o.steps.push(StepLine {
                    k: dec(0),
                    velocity_bits: hex(1),
                    force_bits: hex(2),
                    estimator_flags: hex(3) as u8,
                    firmware_flags: hex(4) as u8,
                    ticks: dec(5),
                    observer,
                });
                continue;
            }
            let mut tag = Vec::new();
            let mut fields = Fields::default();
            for w in line.split_ascii_whitespace() {
                match w.split_once('=') {
                    Some((k, v)) => {
                        fields.0.insert(k.to_string(), v.to_string());
                    }
                    None if fields.0.is_empty() => tag.push(w),
                    None => {}
                }
            }
            let tag = tag.join(" ");
            if tag == "digest" {
                o.digests.push(DigestLine {
                    chunk: fields.num("chunk"),
                    first: fields.num("first"),
                    steps: fields.num("steps"),
                    crc: fields.num("crc"),
                });
            } else if !tag.is_empty() {
                o.tagged.insert(tag, fields);
            }
        }
        o
    }

    /// The fields of the line tagged `tag`.
    pub fn get(&self, tag: &str) -> Option<&Fields> {
        self.tagged.get(tag)
    }

    /// The fields of the line tagged `tag`; panics (showing the output) if absent.
    pub fn expect(&self, tag: &str) -> &Fields {
        self.get(tag).unwrap_or_else(|| {
            panic!(
                "no `{tag}` line in the firmware output:\n{}",
                self.lines.join("\n")
            )
        })
    }

    /// The `weights-error` line as printed.
    pub fn weights_error_line(&self) -> Option<&str> {
        self.lines
            .iter()
            .map(String::as_str)
            .find(|l| l.starts_with("weights-error"))
    }
}

/// The firmware's weights slot (`.nemm_weights`) and recorded trace (`.nemm_trace`) as linked.
#[derive(Debug, Clone)]
pub struct Contents {
    /// The whole weights slot.
    pub slot: Vec<u8>,
    /// The trace.
    pub trace: Vec<u8>,
}

/// Section name of the weights slot.
pub const WEIGHTS_SECTION: &str = ".nemm_weights";
/// Section name of the recorded trace.
pub const TRACE_SECTION: &str = ".nemm_trace";

impl Contents {
    /// Reads both from an image.
    pub fn of(elf: &Elf) -> Self {
        Self {
            slot: elf
                .section_data(WEIGHTS_SECTION)
                .expect("weights slot")
                .to_vec(),
            trace: elf.section_data(TRACE_SECTION).expect("trace").to_vec(),
        }
    }

    /// The blob in the slot.
    pub fn blob(&self) -> &[u8] {
        nemm_firmware::slot::blob(&self.slot).expect("the built-in slot holds a blob")
    }
}

/// A weights slot holding `blob` (header, blob, erased flash up to `capacity`); the length
/// field says `len` (normally `blob.len()`).
pub fn slot_with_len(blob: &[u8], len: u32, capacity: usize) -> Vec<u8> {
    let mut s = vec![0; capacity];
    nemm_firmware::slot::encode(blob, &mut s).expect("blob fits the slot");
    s[..nemm_firmware::slot::HEADER_LEN].copy_from_slice(&nemm_firmware::slot::header(len));
    s
}

/// A weights slot holding `blob`.
pub fn slot_with(blob: &[u8]) -> Vec<u8> {
    slot_with_len(blob, blob.len() as u32, nemm_firmware::slot::CAPACITY)
}

/// Writes `elf` with its weights slot replaced by `slot` to a fresh file under the target
/// directory and returns its path.
pub fn image_with_slot(elf: &Elf, slot: &[u8], name: &str) -> PathBuf {
    let bytes = elf
        .patched(WEIGHTS_SECTION, slot)
        .expect("patch the weights slot");
    let dir = scratch_dir();
    let path = dir.join(format!("{name}.elf"));
    std::fs::write(&path, bytes).expect("write the patched image");
    path
}

/// A directory for patched images: `$CARGO_TARGET_TMPDIR` (integration tests) or the system
/// temporary directory, plus the process id.
pub fn scratch_dir() -> PathBuf {
    let base = option_env!("CARGO_TARGET_TMPDIR")
        .map(PathBuf::from)
        .unwrap_or_else(std::env::temp_dir);
    let dir = base.join(format!("nemm-qemu-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("create the scratch directory");
    dir
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_step_lines_with_and_without_the_observer() {
        let o = Output::parse(
            "s 7 3f800000 c0000000 05 04 321\n\
             s 8 3f800000 c0000000 00 00 0 measured=0x40000000 alpha=0x3e800000 \
             band=0x3f000000 flags=0x21\n\
             exit code=0 last_alpha=0x3e800000\n",
        );
        assert_eq!(o.steps.len(), 2);
        assert_eq!((o.steps[0].k, o.steps[0].ticks), (7, 321));
        assert_eq!(o.steps[0].observer, None);
        let p = o.steps[1].observer.expect("observer fields");
        assert_eq!((p.alpha(), p.band(), p.flags), (0.25, 0.5, 0x21));
        assert_eq!(f32::from_bits(p.measured_bits), 2.0);
        assert_eq!(o.expect("exit").num("last_alpha"), 0.25f32.to_bits());
    }

    #[test]
    #[should_panic(expected = "bad step line")]
    fn a_partial_observer_part_is_refused() {
        Output::parse("s 8 3f800000 c0000000 00 00 0 measured=0x40000000 alpha=0x3e800000\n");
    }
}
