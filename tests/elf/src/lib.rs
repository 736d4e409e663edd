//! Reading (and patching one section of) the firmware's 32-bit little-endian ARM ELF images:
//! section contents, symbols, flash and RAM use, and the direct call graph of the Thumb-2
//! code.
//!
//! The ELF parsing is the [`object`] crate's and the demangling [`rustc_demangle`]'s; what is
//! left here is the firmware's view of them (what counts as flash and RAM) and the decoding
//! of Thumb-2 branches for the call graph. Shared by the QEMU tests (`nemm_tests::elf`) and
//! `cargo xtask`.
#![deny(missing_docs)]

use object::{Object, ObjectSection, ObjectSymbol, SectionFlags, SymbolKind};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::Path;

/// `SHF_ALLOC`.
const SHF_ALLOC: u32 = object::elf::SHF_ALLOC.0 as u32;
/// `SHF_WRITE`.
const SHF_WRITE: u32 = object::elf::SHF_WRITE.0 as u32;
/// `SHF_EXECINSTR`.
const SHF_EXECINSTR: u32 = object::elf::SHF_EXECINSTR.0 as u32;

/// One section.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Section {
    /// Name (`.text`, `.nemm_weights`, ...).
    pub name: String,
    /// `sh_flags`.
    pub flags: u32,
    /// Address in the target's memory map.
    pub addr: u32,
    /// Offset of the contents in the file; `None` for `.bss`-like sections (no bytes in the
    /// file).
    pub offset: Option<u32>,
    /// Size in bytes.
    pub size: u32,
}

impl Section {
    /// Occupies target memory.
    pub fn is_alloc(&self) -> bool {
        self.flags & SHF_ALLOC != 0
    }
    /// Has contents in the image (not `.bss`-like).
    pub fn has_bits(&self) -> bool {
        self.offset.is_some()
    }
    /// Writable at run time (lives in RAM).
    pub fn is_write(&self) -> bool {
        self.flags & SHF_WRITE != 0
    }
    /// Holds code.
    pub fn is_exec(&self) -> bool {
        self.flags & SHF_EXECINSTR != 0
    }
}

/// One symbol.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Symbol {
    /// Name as linked (possibly mangled).
    pub name: String,
    /// Value (address; bit 0 set for Thumb functions).
    pub value: u32,
    /// Size in bytes.
    pub size: u32,
    /// A function (`STT_FUNC`).
    pub function: bool,
}

impl Symbol {
    /// A function symbol with a body.
    pub fn is_function(&self) -> bool {
        self.function && self.size > 0
    }
    /// Start address of a function (Thumb bit cleared).
    pub fn start(&self) -> u32 {
        self.value & !1
    }
}

/// A parsed ELF file.
#[derive(Debug, Clone)]
pub struct Elf {
    /// The file.
    pub bytes: Vec<u8>,
    /// Its sections.
    pub sections: Vec<Section>,
    /// Its symbols (empty if stripped).
    pub symbols: Vec<Symbol>,
}

/// A 64-bit field of `object`'s that a 32-bit image keeps in 32 bits.
fn narrow(v: u64, what: &str) -> Result<u32, String> {
    u32::try_from(v).map_err(|_| format!("{what} {v:#x} does not fit a 32-bit image"))
}

impl Elf {
    /// Parses a 32-bit little-endian ELF file.
    pub fn parse(bytes: Vec<u8>) -> Result<Self, String> {
        let file = object::File::parse(&*bytes).map_err(|e| e.to_string())?;
        if file.format() != object::BinaryFormat::Elf || file.is_64() || !file.is_little_endian() {
            return Err("not a 32-bit little-endian ELF file".into());
        }
        let mut sections = Vec::new();
        for s in file.sections() {
            let flags = match s.flags() {
                SectionFlags::Elf { sh_flags, .. } => narrow(sh_flags.0, "sh_flags")?,
                _ => 0,
            };
            let offset = s
                .file_range()
                .map(|(at, _)| narrow(at, "section offset"))
                .transpose()?;
            sections.push(Section {
                name: s.name().map_err(|e| e.to_string())?.to_string(),
                flags,
                addr: narrow(s.address(), "section address")?,
                offset,
                size: narrow(s.size(), "section size")?,
            });
        }
        let mut symbols = Vec::new();
        for s in file.symbols() {
            symbols.push(Symbol {
                name: s.name().map_err(|e| e.to_string())?.to_string(),
                value: narrow(s.address(), "symbol value")?,
                size: narrow(s.size(), "symbol size")?,
                function: s.kind() == SymbolKind::Text,
            });
        }
        Ok(Self {
            bytes,
            sections,
            symbols,
        })
    }

    /// Reads and parses a file.
    pub fn read(path: &Path) -> Result<Self, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::parse(bytes).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// The section called `name`.
    pub fn section(&self, name: &str) -> Option<&Section> {
        self.sections.iter().find(|s| s.name == name)
    }

    /// The symbol called `name` exactly (as linked).
    pub fn symbol(&self, name: &str) -> Option<&Symbol> {
        self.symbols.iter().find(|s| s.name == name)
    }

    /// The byte range of section `name` in the file.
    fn section_range(&self, name: &str) -> Result<std::ops::Range<usize>, String> {
        let s = self
            .section(name)
            .ok_or_else(|| format!("no section {name}"))?;
        let start = s
            .offset
            .ok_or_else(|| format!("section {name} has no contents"))? as usize;
        let range = start..start + s.size as usize;
        if range.end > self.bytes.len() {
            return Err(format!("section {name} lies outside the file"));
        }
        Ok(range)
    }

    /// The contents of section `name`.
    pub fn section_data(&self, name: &str) -> Result<&[u8], String> {
        Ok(&self.bytes[self.section_range(name)?])
    }

    /// Replaces the contents of section `name` (same size) and returns the patched file.
    pub fn patched(&self, name: &str, data: &[u8]) -> Result<Vec<u8>, String> {
        let range = self.section_range(name)?;
        if data.len() != range.len() {
            return Err(format!(
                "section {name} holds {} bytes, got {}",
                range.len(),
                data.len()
            ));
        }
        let mut out = self.bytes.clone();
        out[range].copy_from_slice(data);
        Ok(out)
    }

    /// Flash and RAM use.
    pub fn memory_use(&self) -> MemoryUse {
        let mut m = MemoryUse::default();
        for s in self.sections.iter().filter(|s| s.is_alloc() && s.size > 0) {
            if s.has_bits() {
                m.flash += s.size;
            }
            if s.is_write() {
                m.ram += s.size;
            }
            m.sections.push((s.name.clone(), s.addr, s.size));
        }
        m
    }

    /// The function symbols, by start address.
    pub fn functions(&self) -> BTreeMap<u32, &Symbol> {
        let mut f = BTreeMap::new();
        for s in self.symbols.iter().filter(|s| s.is_function()) {
            f.entry(s.start()).or_insert(s);
        }
        f
    }

    /// The first function symbol whose name is `name` or whose demangled name is or ends
    /// with `name`.
    pub fn function(&self, name: &str) -> Option<&Symbol> {
        self.symbols.iter().filter(|s| s.is_function()).find(|s| {
            let d = demangle(&s.name);
            s.name == name || d == name || d.ends_with(&format!("::{name}"))
        })
    }

    /// Direct call graph of the Thumb-2 code: for every function, the functions it calls or
    /// branches to (`bl`, `b`, `b.w`, conditional branches leaving the function), and whether
    /// it makes indirect calls (`blx rN`). Literal pools (between `$d` and `$t` mapping
    /// symbols) are skipped.
    pub fn call_graph(&self) -> CallGraph {
        let funcs = self.functions();
        let ranges: Vec<(u32, u32)> = funcs.values().map(|s| (s.start(), s.size)).collect();
        let owner = |addr: u32| -> Option<u32> {
            let i = ranges.partition_point(|&(start, _)| start <= addr);
            let &(start, size) = ranges.get(i.checked_sub(1)?)?;
            (addr < start + size).then_some(start)
        };
        // Data regions inside code ($d .. next $t / $a).
        let mut marks: Vec<(u32, bool)> = self
            .symbols
            .iter()
            .filter(|s| s.name.starts_with("$d") || s.name.starts_with("$t"))
            .map(|s| (s.value, s.name.starts_with("$d")))
            .collect();
        marks.sort();
        let is_data = |addr: u32| -> bool {
            let i = marks.partition_point(|&(a, _)| a <= addr);
            i > 0 && marks[i - 1].1
        };
        let mut g = CallGraph::default();
        for sec in self.sections.iter().filter(|s| s.is_exec() && s.has_bits()) {
            let Ok(code) = self.section_data(&sec.name) else {
                continue;
            };
            let halfword = |pc: u32| -> u16 {
                let at = (pc - sec.addr) as usize;
                u16::from_le_bytes([code[at], code[at + 1]])
            };
            for (&start, sym) in funcs.range(sec.addr..sec.addr + sec.size) {
                let entry = g.callees.entry(start).or_default();
                let mut pc = start;
                let end = (start + sym.size).min(sec.addr + sec.size);
                while pc + 2 <= end {
                    if is_data(pc) {
                        pc += 2;
                        continue;
                    }
                    let hw1 = halfword(pc);
                    let wide = matches!(hw1 >> 11, 0b11101..=0b11111);
                    let target = if wide {
                        if pc + 4 > end {
                            break;
                        }
                        thumb2_branch_target(pc, hw1, halfword(pc + 2))
                    } else {
                        if hw1 & 0xFF87 == 0x4780 {
                            g.indirect.insert(start);
                        }
                        thumb_branch_target(pc, hw1)
                    };
                    if let Some(t) = target.and_then(owner) {
                        if t != start {
                            entry.insert(t);
                        }
                    }
                    pc += if wide { 4 } else { 2 };
                }
            }
        }
        for (&start, sym) in &funcs {
            g.names.insert(start, demangle(&sym.name));
        }
        g
    }
}

/// Target of a 16-bit Thumb branch (`b` T1/T2) at `pc`, if `hw` is one.
fn thumb_branch_target(pc: u32, hw: u16) -> Option<u32> {
    if hw >> 11 == 0b11100 {
        let imm = (u32::from(hw & 0x7FF) << 21) as i32 >> 20;
        return Some(pc.wrapping_add(4).wrapping_add(imm as u32));
    }
    if hw >> 12 == 0b1101 && (hw >> 9) & 0b111 != 0b111 {
        let imm = (u32::from(hw & 0xFF) << 24) as i32 >> 23;
        return Some(pc.wrapping_add(4).wrapping_add(imm as u32));
    }
    None
}

/// Target of a 32-bit Thumb-2 branch (`bl`, `b.w` T4, conditional `b.w` T3) at `pc`.
fn thumb2_branch_target(pc: u32, hw1: u16, hw2: u16) -> Option<u32> {
    if hw1 >> 11 != 0b11110 || hw2 & 0x8000 == 0 {
        return None;
    }
    let s = u32::from((hw1 >> 10) & 1);
    let j1 = u32::from((hw2 >> 13) & 1);
    let j2 = u32::from((hw2 >> 11) & 1);
    let imm11 = u32::from(hw2 & 0x7FF);
    let off = match hw2 & 0xD000 {
        // BL (T1) and B.W (T4).
        0xD000 | 0x9000 => {
            let i1 = !(j1 ^ s) & 1;
            let i2 = !(j2 ^ s) & 1;
            let imm10 = u32::from(hw1 & 0x3FF);
            let raw = (s << 24) | (i1 << 23) | (i2 << 22) | (imm10 << 12) | (imm11 << 1);
            ((raw << 7) as i32) >> 7
        }
        // B<cond>.W (T3); cond 111x are other instructions.
        0x8000 if (hw1 >> 7) & 0b111 != 0b111 => {
            let imm6 = u32::from(hw1 & 0x3F);
            let raw = (s << 20) | (j2 << 19) | (j1 << 18) | (imm6 << 12) | (imm11 << 1);
            ((raw << 11) as i32) >> 11
        }
        _ => return None,
    };
    Some(pc.wrapping_add(4).wrapping_add(off as u32))
}

/// Flash and RAM use of an image (like `size -A`, without the debug sections).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct MemoryUse {
    /// Bytes programmed into flash (code, read-only data, trace, weights slot, `.data`'s
    /// initial values).
    pub flash: u32,
    /// Bytes of RAM taken by statics (`.data`, `.bss`, `.uninit`); the stack comes on top.
    pub ram: u32,
    /// `(name, address, size)` of every allocated section.
    pub sections: Vec<(String, u32, u32)>,
}

impl MemoryUse {
    /// Size of section `name` (0 if absent).
    pub fn size_of(&self, name: &str) -> u32 {
        self.sections
            .iter()
            .find(|(n, _, _)| n == name)
            .map_or(0, |s| s.2)
    }

    /// A table: one line per section, then the totals.
    pub fn table(&self) -> String {
        let mut t = format!("{:<16} {:>10} {:>10}\n", "section", "size", "addr");
        for (n, a, s) in &self.sections {
            t += &format!("{n:<16} {s:>10} {a:>#10x}\n");
        }
        t += &format!(
            "flash {} bytes ({:.1} KiB), RAM {} bytes ({:.1} KiB) of statics\n",
            self.flash,
            f64::from(self.flash) / 1024.0,
            self.ram,
            f64::from(self.ram) / 1024.0
        );
        t
    }
}

/// The direct call graph of an image ([`Elf::call_graph`]).
#[derive(Debug, Clone, Default)]
pub struct CallGraph {
    /// Callees (function start addresses) of each function.
    pub callees: BTreeMap<u32, BTreeSet<u32>>,
    /// Functions with an indirect call (`blx rN`).
    pub indirect: BTreeSet<u32>,
    /// Demangled names.
    pub names: BTreeMap<u32, String>,
}

impl CallGraph {
    /// Name of the function at `addr`.
    pub fn name(&self, addr: u32) -> &str {
        self.names.get(&addr).map_or("?", String::as_str)
    }

    /// Every function reachable from `root`, with the caller through which it was first
    /// reached (breadth first).
    pub fn reachable(&self, root: u32) -> BTreeMap<u32, Option<u32>> {
        let mut seen = BTreeMap::new();
        seen.insert(root, None);
        let mut queue = VecDeque::from([root]);
        while let Some(f) = queue.pop_front() {
            for &c in self.callees.get(&f).into_iter().flatten() {
                if let std::collections::btree_map::Entry::Vacant(e) = seen.entry(c) {
                    e.insert(Some(f));
                    queue.push_back(c);
                }
            }
        }
        seen
    }

    /// The call chain from the root of `reached` to `to`, as names.
    pub fn chain(&self, reached: &BTreeMap<u32, Option<u32>>, to: u32) -> Vec<String> {
        let mut chain = vec![self.name(to).to_string()];
        let mut at = to;
        while let Some(Some(parent)) = reached.get(&at) {
            chain.push(self.name(*parent).to_string());
            at = *parent;
        }
        chain.reverse();
        chain
    }
}

/// A readable name for a symbol: Rust symbols (v0 `_R...` and legacy `_ZN...E`) demangled
/// without their crate disambiguators and hashes, such as
/// `<nemm_kernels::mlp::Scaler<1313>>::scale`; other names as they are.
pub fn demangle(name: &str) -> String {
    format!("{:#}", rustc_demangle::demangle(name))
}

/// True for the symbols a panic goes through: `core::panicking::*`, the panic handler
/// (`rust_begin_unwind`) and any other function with `panic` in its name.
pub fn is_panic_symbol(name: &str) -> bool {
    let d = demangle(name);
    d.contains("panic") || d.contains("rust_begin_unwind")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demangles_legacy_and_v0_names() {
        assert_eq!(
            demangle("_ZN4core9panicking9panic_fmt17h0123456789abcdefE"),
            "core::panicking::panic_fmt"
        );
        assert_eq!(
            demangle("_ZN40_$LT$nemm_core..mlp..Scaler$LT$_$GT$$GT$5scale17h0123456789abcdefE"),
            "<nemm_core::mlp::Scaler<_>>::scale"
        );
        assert_eq!(
            demangle("_RNvNtCscoi5Cl9D7Ug_4core9panicking9panic_fmt"),
            "core::panicking::panic_fmt"
        );
        assert_eq!(
            demangle(
                "_RNvMs0_NtCs2qvOz2mvwox_9nemm_core3mlpINtB5_14CompiledScalerKj521_E4evalCs5XXU9oMLyQy_13nemm_firmware"
            ),
            "<nemm_core::mlp::CompiledScaler<1313>>::eval"
        );
        assert_eq!(demangle("SysTick"), "SysTick");
        assert!(is_panic_symbol(
            "_RNvNtNtCscoi5Cl9D7Ug_4core9panicking11panic_const23panic_const_rem_by_zero"
        ));
        assert!(is_panic_symbol(
            "_RNvCsfgHYwM92fyn_7___rustc17rust_begin_unwind"
        ));
        assert!(!is_panic_symbol("SysTick"));
    }

    /// A relocatable ARM object: `Reset` (at 0) calls `step` (at 8), which calls the panic
    /// function `core::panicking::panic_fmt` (at 16); `idle` (at 20) calls through a
    /// register. Plus a writable `.bss` and a `.nemm_weights` slot.
    fn thumb_object() -> Vec<u8> {
        use object::write::{Object as Writer, Symbol as WSymbol, SymbolSection};
        use object::{
            Architecture, BinaryFormat, Endianness, SectionKind, SymbolFlags, SymbolScope,
        };
        let code: Vec<u8> = [
            0xf000u16, 0xf802, // 0: bl 0x8 (step)
            0x4770, 0xbf00, //    4: bx lr; nop
            0xf000, 0xf802, //    8: bl 0x10 (panic_fmt)
            0x4770, 0xbf00, //    c: bx lr; nop
            0xe7fe, 0xbf00, //   10: b.n . (the panic function spins)
            0x4798, 0x4770, //   14: blx r3; bx lr
        ]
        .iter()
        .flat_map(|h| h.to_le_bytes())
        .collect();
        let mut w = Writer::new(BinaryFormat::Elf, Architecture::Arm, Endianness::Little);
        let text = w.add_section(Vec::new(), b".text".to_vec(), SectionKind::Text);
        w.append_section_data(text, &code, 4);
        let bss = w.add_section(Vec::new(), b".bss".to_vec(), SectionKind::UninitializedData);
        w.append_section_bss(bss, 64, 4);
        let slot = w.add_section(
            Vec::new(),
            b".nemm_weights".to_vec(),
            SectionKind::ReadOnlyData,
        );
        w.append_section_data(slot, &[0xFF; 16], 4);
        for (name, at, size) in [
            ("Reset", 0, 8),
            ("_RNvCs1234_13nemm_firmware4step", 8, 8),
            ("_ZN4core9panicking9panic_fmt17h0123456789abcdefE", 16, 4),
            ("idle", 20, 4),
        ] {
            w.add_symbol(WSymbol {
                name: name.as_bytes().to_vec(),
                value: at | 1,
                size,
                kind: object::SymbolKind::Text,
                scope: SymbolScope::Linkage,
                weak: false,
                section: SymbolSection::Section(text),
                flags: SymbolFlags::None,
            });
        }
        w.write().expect("write the object")
    }

    #[test]
    fn reads_sections_symbols_and_memory_use() {
        let elf = Elf::parse(thumb_object()).expect("parse");
        assert!(elf
            .section(".text")
            .is_some_and(|s| s.is_exec() && s.has_bits()));
        let bss = elf.section(".bss").expect(".bss");
        assert!(bss.is_write() && !bss.has_bits() && bss.size == 64);
        assert!(elf.section_data(".bss").is_err());
        let m = elf.memory_use();
        assert_eq!((m.flash, m.ram), (24 + 16, 64));
        assert_eq!(m.size_of(".nemm_weights"), 16);
        let step = elf.function("step").expect("found by its demangled tail");
        assert_eq!((step.start(), step.size), (8, 8));
        assert!(elf.symbol("Reset").is_some_and(Symbol::is_function));
        // Patching a section changes exactly its bytes.
        let patched = Elf::parse(elf.patched(".nemm_weights", &[7; 16]).expect("patch"))
            .expect("parse the patched file");
        assert_eq!(patched.section_data(".nemm_weights"), Ok(&[7u8; 16][..]));
        assert_eq!(patched.section_data(".text"), elf.section_data(".text"));
        assert!(elf.patched(".nemm_weights", &[7; 15]).is_err());
        assert!(Elf::parse(b"\x7fELF but not really".to_vec()).is_err());
    }

    #[test]
    fn the_call_graph_reaches_a_panic_through_a_call_chain() {
        let elf = Elf::parse(thumb_object()).expect("parse");
        let g = elf.call_graph();
        let reached = g.reachable(0);
        let panics: Vec<u32> = elf
            .symbols
            .iter()
            .filter(|s| s.is_function() && is_panic_symbol(&s.name))
            .map(Symbol::start)
            .collect();
        assert_eq!(panics, [16]);
        assert!(reached.contains_key(&16));
        assert_eq!(
            g.chain(&reached, 16),
            ["Reset", "nemm_firmware::step", "core::panicking::panic_fmt"]
        );
        // From `step`'s callee alone nothing else is reached; `idle` calls through a register.
        assert_eq!(g.reachable(16).len(), 1);
        assert_eq!(g.indirect, BTreeSet::from([20]));
    }

    #[test]
    fn decodes_thumb_branches() {
        // Encodings and targets as arm-none-eabi-objdump shows them in the firmware.
        assert_eq!(thumb2_branch_target(0x1130, 0xf009, 0xfa22), Some(0xa578)); // bl
        assert_eq!(thumb2_branch_target(0xa57c, 0xf7ff, 0xfff8), Some(0xa570)); // bl back
        assert_eq!(thumb2_branch_target(0x82e, 0xf000, 0xbbb4), Some(0xf9a)); // b.w
        assert_eq!(thumb2_branch_target(0x548, 0xf000, 0x85f2), Some(0x1130)); // beq.w
        assert_eq!(thumb2_branch_target(0x640, 0xf300, 0x80a6), Some(0x790)); // bgt.w
        assert_eq!(thumb_branch_target(0x40c, 0xd001), Some(0x412)); // beq.n
        assert_eq!(thumb_branch_target(0x410, 0xe7fb), Some(0x40a)); // b.n

        // Not branches: push, vmov, ldrb.w.
        assert_eq!(thumb_branch_target(0x3000, 0xb580), None);
        assert_eq!(thumb2_branch_target(0x3000, 0xee10, 0x0a10), None);
        assert_eq!(thumb2_branch_target(0x4a0, 0xf89b, 0x00dd), None);
    }
}
