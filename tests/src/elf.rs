//! A small reader (and section patcher) for the firmware's 32-bit little-endian ARM ELF
//! files, std only: section contents, symbols, flash and RAM use, and the direct call graph
//! of the Thumb-2 code.
//!
//! Shared by the QEMU tests (`nemm_tests::elf`) and `cargo xtask` (included by path, so that
//! xtask stays free of dependencies).

use std::collections::{BTreeMap, BTreeSet, VecDeque};

/// `SHT_SYMTAB`.
const SHT_SYMTAB: u32 = 2;
/// `SHT_NOBITS` (`.bss`-like: no bytes in the file).
const SHT_NOBITS: u32 = 8;
/// `SHF_WRITE`.
const SHF_WRITE: u32 = 1;
/// `SHF_ALLOC`.
const SHF_ALLOC: u32 = 2;
/// `SHF_EXECINSTR`.
const SHF_EXECINSTR: u32 = 4;
/// `STT_FUNC`.
const STT_FUNC: u8 = 2;

/// One section header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Section {
    /// Name (`.text`, `.nemm_weights`, ...).
    pub name: String,
    /// `sh_type`.
    pub kind: u32,
    /// `sh_flags`.
    pub flags: u32,
    /// Address in the target's memory map.
    pub addr: u32,
    /// Offset of the contents in the file.
    pub offset: u32,
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
        self.kind != SHT_NOBITS
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
    /// `STT_*` type.
    pub kind: u8,
    /// Section index.
    pub shndx: u16,
}

impl Symbol {
    /// A function symbol with a body.
    pub fn is_function(&self) -> bool {
        self.kind == STT_FUNC && self.size > 0
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

fn u16_at(b: &[u8], at: usize) -> Result<u16, String> {
    b.get(at..at + 2)
        .map(|s| u16::from_le_bytes([s[0], s[1]]))
        .ok_or_else(|| format!("ELF truncated at {at:#x}"))
}

fn u32_at(b: &[u8], at: usize) -> Result<u32, String> {
    b.get(at..at + 4)
        .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
        .ok_or_else(|| format!("ELF truncated at {at:#x}"))
}

fn c_str(b: &[u8], at: usize) -> String {
    let s = b.get(at..).unwrap_or(&[]);
    let end = s.iter().position(|&c| c == 0).unwrap_or(s.len());
    String::from_utf8_lossy(&s[..end]).into_owned()
}

impl Elf {
    /// Parses a 32-bit little-endian ELF file.
    pub fn parse(bytes: Vec<u8>) -> Result<Self, String> {
        if bytes.get(..4) != Some(b"\x7fELF") {
            return Err("not an ELF file".into());
        }
        if bytes.get(4) != Some(&1) || bytes.get(5) != Some(&1) {
            return Err("not a 32-bit little-endian ELF file".into());
        }
        let shoff = u32_at(&bytes, 0x20)? as usize;
        let shentsize = u16_at(&bytes, 0x2E)? as usize;
        let shnum = u16_at(&bytes, 0x30)? as usize;
        let shstrndx = u16_at(&bytes, 0x32)? as usize;
        let mut raw = Vec::new();
        for i in 0..shnum {
            let h = shoff + i * shentsize;
            raw.push((
                u32_at(&bytes, h)?,
                u32_at(&bytes, h + 4)?,
                u32_at(&bytes, h + 8)?,
                u32_at(&bytes, h + 12)?,
                u32_at(&bytes, h + 16)?,
                u32_at(&bytes, h + 20)?,
                u32_at(&bytes, h + 24)?,
            ));
        }
        let strtab_off = raw.get(shstrndx).map(|r| r.4 as usize).unwrap_or(0);
        let sections: Vec<Section> = raw
            .iter()
            .map(|&(name, kind, flags, addr, offset, size, _)| Section {
                name: c_str(&bytes, strtab_off + name as usize),
                kind,
                flags,
                addr,
                offset,
                size,
            })
            .collect();
        let mut symbols = Vec::new();
        for &(_, kind, _, _, offset, size, link) in &raw {
            if kind != SHT_SYMTAB {
                continue;
            }
            let names = raw.get(link as usize).map(|r| r.4 as usize).unwrap_or(0);
            for e in (offset as usize..(offset + size) as usize).step_by(16) {
                symbols.push(Symbol {
                    name: c_str(&bytes, names + u32_at(&bytes, e)? as usize),
                    value: u32_at(&bytes, e + 4)?,
                    size: u32_at(&bytes, e + 8)?,
                    kind: bytes.get(e + 12).copied().unwrap_or(0) & 0xF,
                    shndx: u16_at(&bytes, e + 14)?,
                });
            }
        }
        Ok(Self {
            bytes,
            sections,
            symbols,
        })
    }

    /// Reads and parses a file.
    pub fn read(path: &std::path::Path) -> Result<Self, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::parse(bytes).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// The section called `name`.
    pub fn section(&self, name: &str) -> Option<&Section> {
        self.sections.iter().find(|s| s.name == name)
    }

    /// The contents of section `name`.
    pub fn section_data(&self, name: &str) -> Result<&[u8], String> {
        let s = self
            .section(name)
            .ok_or_else(|| format!("no section {name}"))?;
        if !s.has_bits() {
            return Err(format!("section {name} has no contents"));
        }
        self.bytes
            .get(s.offset as usize..(s.offset + s.size) as usize)
            .ok_or_else(|| format!("section {name} lies outside the file"))
    }

    /// Replaces the contents of section `name` (same size) and returns the patched file.
    pub fn patched(&self, name: &str, data: &[u8]) -> Result<Vec<u8>, String> {
        let s = self
            .section(name)
            .ok_or_else(|| format!("no section {name}"))?;
        if data.len() != s.size as usize {
            return Err(format!(
                "section {name} holds {} bytes, got {}",
                s.size,
                data.len()
            ));
        }
        self.section_data(name)?;
        let mut out = self.bytes.clone();
        out[s.offset as usize..(s.offset + s.size) as usize].copy_from_slice(data);
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
            let code = match self.section_data(&sec.name) {
                Ok(c) => c,
                Err(_) => continue,
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
                    let at = (pc - sec.addr) as usize;
                    let hw1 = u16::from_le_bytes([code[at], code[at + 1]]);
                    let wide = matches!(hw1 >> 11, 0b11101..=0b11111);
                    let target = if wide {
                        if pc + 4 > end {
                            break;
                        }
                        let hw2 = u16::from_le_bytes([code[at + 2], code[at + 3]]);
                        thumb2_branch_target(pc, hw1, hw2)
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

/// Demangles a Rust symbol, v0 (`_R...`) or legacy (`_ZN...E`, without the hash), into a
/// readable path such as `<nemm_core::mlp::Scaler<1313>>::scale`; other names (and anything
/// this small demangler does not follow) are returned as they are.
pub fn demangle(name: &str) -> String {
    if let Some(rest) = name.strip_prefix("_R") {
        let mut p = V0 {
            s: name.as_bytes(),
            pos: 2 + rest.bytes().take_while(u8::is_ascii_digit).count(),
            depth: 0,
        };
        return p.path().unwrap_or_else(|_| name.to_string());
    }
    demangle_legacy(name).unwrap_or_else(|| name.to_string())
}

fn demangle_legacy(name: &str) -> Option<String> {
    let mut rest = name.strip_prefix("_ZN")?;
    let mut parts: Vec<String> = Vec::new();
    while !rest.starts_with('E') {
        let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
        let len: usize = rest.get(..digits)?.parse().ok()?;
        let part = rest.get(digits..digits + len)?;
        rest = &rest[digits + len..];
        let is_hash = part.len() == 17
            && part.starts_with('h')
            && part[1..].bytes().all(|c| c.is_ascii_hexdigit());
        if !is_hash {
            parts.push(unescape_legacy(part));
        }
    }
    Some(parts.join("::"))
}

fn unescape_legacy(part: &str) -> String {
    let part = part
        .strip_prefix('_')
        .filter(|p| p.starts_with('$'))
        .unwrap_or(part);
    let mut s = part.to_string();
    for (from, to) in [
        ("$LT$", "<"),
        ("$GT$", ">"),
        ("$RF$", "&"),
        ("$BP$", "*"),
        ("$LP$", "("),
        ("$RP$", ")"),
        ("$C$", ","),
        ("$u20$", " "),
        ("$u27$", "'"),
        ("$u5b$", "["),
        ("$u5d$", "]"),
        ("$u7b$", "{"),
        ("$u7d$", "}"),
        ("$u3b$", ";"),
        ("$u2b$", "+"),
        ("..", "::"),
    ] {
        s = s.replace(from, to);
    }
    s
}

/// A recursive-descent reader of the v0 mangling grammar (enough of it for readable names).
struct V0<'a> {
    s: &'a [u8],
    pos: usize,
    depth: u32,
}

type V0Result = Result<String, ()>;

impl V0<'_> {
    fn peek(&self) -> Option<u8> {
        self.s.get(self.pos).copied()
    }
    fn next(&mut self) -> Result<u8, ()> {
        let c = self.peek().ok_or(())?;
        self.pos += 1;
        Ok(c)
    }
    fn eat(&mut self, c: u8) -> bool {
        let yes = self.peek() == Some(c);
        if yes {
            self.pos += 1;
        }
        yes
    }
    fn base62(&mut self) -> Result<u64, ()> {
        if self.eat(b'_') {
            return Ok(0);
        }
        let mut v: u64 = 0;
        loop {
            let c = self.next()?;
            let d = match c {
                b'0'..=b'9' => c - b'0',
                b'a'..=b'z' => c - b'a' + 10,
                b'A'..=b'Z' => c - b'A' + 36,
                b'_' => return v.checked_add(1).ok_or(()),
                _ => return Err(()),
            };
            v = v
                .checked_mul(62)
                .and_then(|v| v.checked_add(u64::from(d)))
                .ok_or(())?;
        }
    }
    fn disambiguator(&mut self) -> Result<u64, ()> {
        if self.eat(b's') {
            Ok(self.base62()? + 1)
        } else {
            Ok(0)
        }
    }
    fn undisambiguated_ident(&mut self) -> V0Result {
        let _punycode = self.eat(b'u');
        let digits = self.s[self.pos..]
            .iter()
            .take_while(|c| c.is_ascii_digit())
            .count();
        let len: usize = std::str::from_utf8(&self.s[self.pos..self.pos + digits])
            .map_err(|_| ())?
            .parse()
            .map_err(|_| ())?;
        self.pos += digits;
        self.eat(b'_');
        let bytes = self.s.get(self.pos..self.pos + len).ok_or(())?;
        self.pos += len;
        Ok(String::from_utf8_lossy(bytes).into_owned())
    }
    fn backref(&mut self, f: fn(&mut Self) -> V0Result) -> V0Result {
        let start = self.pos - 1;
        let at = 2 + usize::try_from(self.base62()?).map_err(|_| ())?;
        if at >= start || self.depth > 64 {
            return Err(());
        }
        let saved = self.pos;
        self.pos = at;
        self.depth += 1;
        let r = f(self);
        self.depth -= 1;
        self.pos = saved;
        r
    }
    fn path(&mut self) -> V0Result {
        match self.next()? {
            b'C' => {
                self.disambiguator()?;
                self.undisambiguated_ident()
            }
            b'M' => {
                self.disambiguator()?;
                self.path()?;
                Ok(format!("<{}>", self.ty()?))
            }
            b'X' => {
                self.disambiguator()?;
                self.path()?;
                let ty = self.ty()?;
                Ok(format!("<{ty} as {}>", self.path()?))
            }
            b'Y' => {
                let ty = self.ty()?;
                Ok(format!("<{ty} as {}>", self.path()?))
            }
            b'N' => {
                let ns = self.next()?;
                let prefix = self.path()?;
                let dis = self.disambiguator()?;
                let name = self.undisambiguated_ident()?;
                Ok(match ns {
                    b'C' => format!("{prefix}::{{closure#{dis}}}"),
                    b'S' => format!("{prefix}::{{shim:{name}#{dis}}}"),
                    _ if name.is_empty() => prefix,
                    _ => format!("{prefix}::{name}"),
                })
            }
            b'I' => {
                let p = self.path()?;
                let mut args = Vec::new();
                while !self.eat(b'E') {
                    args.push(self.generic_arg()?);
                }
                Ok(format!("{p}<{}>", args.join(", ")))
            }
            b'B' => self.backref(Self::path),
            _ => Err(()),
        }
    }
    fn generic_arg(&mut self) -> V0Result {
        if self.eat(b'L') {
            self.base62()?;
            Ok("'_".into())
        } else if self.eat(b'K') {
            self.konst()
        } else {
            self.ty()
        }
    }
    fn konst(&mut self) -> V0Result {
        match self.next()? {
            b'p' => Ok("_".into()),
            b'B' => self.backref(Self::konst),
            ty => {
                let negative = self.eat(b'n');
                let mut v: u128 = 0;
                loop {
                    let c = self.next()?;
                    if c == b'_' {
                        break;
                    }
                    let d = (c as char).to_digit(16).ok_or(())?;
                    v = v.wrapping_mul(16).wrapping_add(u128::from(d));
                }
                Ok(match ty {
                    b'b' => (v != 0).to_string(),
                    _ if negative => format!("-{v}"),
                    _ => v.to_string(),
                })
            }
        }
    }
    fn ty(&mut self) -> V0Result {
        let c = self.next()?;
        let basic = match c {
            b'a' => "i8",
            b'b' => "bool",
            b'c' => "char",
            b'd' => "f64",
            b'e' => "str",
            b'f' => "f32",
            b'h' => "u8",
            b'i' => "isize",
            b'j' => "usize",
            b'l' => "i32",
            b'm' => "u32",
            b'n' => "i128",
            b'o' => "u128",
            b's' => "i16",
            b't' => "u16",
            b'u' => "()",
            b'v' => "...",
            b'x' => "i64",
            b'y' => "u64",
            b'z' => "!",
            b'p' => "_",
            _ => "",
        };
        if !basic.is_empty() {
            return Ok(basic.into());
        }
        match c {
            b'A' => {
                let t = self.ty()?;
                Ok(format!("[{t}; {}]", self.konst()?))
            }
            b'S' => Ok(format!("[{}]", self.ty()?)),
            b'T' => {
                let mut ts = Vec::new();
                while !self.eat(b'E') {
                    ts.push(self.ty()?);
                }
                Ok(format!("({})", ts.join(", ")))
            }
            b'R' | b'Q' => {
                if self.eat(b'L') {
                    self.base62()?;
                }
                let m = if c == b'Q' { "mut " } else { "" };
                Ok(format!("&{m}{}", self.ty()?))
            }
            b'P' => Ok(format!("*const {}", self.ty()?)),
            b'O' => Ok(format!("*mut {}", self.ty()?)),
            b'F' => {
                if self.eat(b'G') {
                    self.base62()?;
                }
                self.eat(b'U');
                if self.eat(b'K') && !self.eat(b'C') {
                    self.undisambiguated_ident()?;
                }
                let mut args = Vec::new();
                while !self.eat(b'E') {
                    args.push(self.ty()?);
                }
                Ok(format!("fn({}) -> {}", args.join(", "), self.ty()?))
            }
            b'D' => {
                if self.eat(b'G') {
                    self.base62()?;
                }
                let mut traits = Vec::new();
                while !self.eat(b'E') {
                    let mut t = self.path()?;
                    while self.eat(b'p') {
                        let name = self.undisambiguated_ident()?;
                        t += &format!("<{name} = {}>", self.ty()?);
                    }
                    traits.push(t);
                }
                if self.eat(b'L') {
                    self.base62()?;
                }
                Ok(format!("dyn {}", traits.join(" + ")))
            }
            b'B' => self.backref(Self::ty),
            _ => {
                self.pos -= 1;
                self.path()
            }
        }
    }
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
        assert_eq!(
            demangle("_RINvNvNtCs5XXU9oMLyQy_13nemm_firmware3app4main21___rtic_init_resourcesNCB2_0EB6_"),
            "nemm_firmware::app::main::__rtic_init_resources<nemm_firmware::app::main::{closure#0}>"
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
