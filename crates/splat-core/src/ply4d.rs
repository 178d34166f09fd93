//! The `.ply4d` 4D scene format (spec: docs/ply4d.md).
//!
//! ```text
//! preamble (32 B) | JSON header | section table (40 B per section) | pad | sections
//! ```
//! Every section is a complete standard 3DGS `.ply` blob starting on a 64-byte boundary:
//! section 0 is the static set shared by all timestamps, then one dynamic set per timestamp.
//! A reader memory-maps the file and touches only the sections it decodes.

use std::fs::{self, File, OpenOptions};
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use memmap2::Mmap;
use serde::{Deserialize, Serialize};

use crate::gaussians::GaussianSet;
use crate::ply::{self, write_atomic, FileError, Result};

pub const MAGIC: [u8; 8] = *b"\x89PLY4D\r\n";
pub const FORMAT_VERSION: u32 = 1;
pub const PREAMBLE_LEN: usize = 32;
pub const TABLE_ENTRY_LEN: usize = 40;
/// Sections start on multiples of this, so they can be mapped and copied page-friendly.
pub const SECTION_ALIGN: u64 = 64;

fn invalid<T>(msg: impl Into<String>) -> Result<T> {
    Err(FileError::Invalid(msg.into()))
}

/// `e` with the file's path in front of its message (format errors only; I/O errors name it).
fn name_file(e: FileError, path: Option<&Path>) -> FileError {
    match (e, path) {
        (FileError::Invalid(msg), Some(path)) => {
            FileError::Invalid(format!("{}: {msg}", path.display()))
        }
        (e, _) => e,
    }
}

/// Axis-aligned bounds of all Gaussian means (finite ones) over every set in the file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bounds {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

/// The panorama camera the scene was lifted from.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraInfo {
    pub position: [f64; 3],
    /// Free-form (e.g. the panorama's size or a `Camera.to_dict()`).
    #[serde(default)]
    pub params: serde_json::Value,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    pub tool_version: String,
    pub config_hash: String,
}

/// Everything in a scene except the Gaussians.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SceneMeta {
    /// Seconds, one per dynamic set.
    pub timestamps: Vec<f64>,
    pub fps: f64,
    pub camera: CameraInfo,
    pub provenance: Provenance,
    /// The rasteriser mode the scene was trained in and is drawn in (docs/rasterizer.md):
    /// absent in files written before the key existed, which are classic.
    #[serde(default)]
    pub antialiased: bool,
    #[serde(default)]
    pub extra: serde_json::Value,
}

/// The JSON header of a `.ply4d` file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ply4dHeader {
    pub format_version: u32,
    pub sh_degree: u32,
    /// `None` when the file has no Gaussian with a finite mean.
    pub bounds: Option<Bounds>,
    #[serde(flatten)]
    pub meta: SceneMeta,
}

/// A 4D scene: a static set shared by all timestamps and one dynamic set per timestamp.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scene4d {
    pub static_set: GaussianSet,
    pub dynamic: Vec<GaussianSet>,
    pub meta: SceneMeta,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SectionKind {
    Static,
    Dynamic,
}

/// One row of the section table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Section {
    pub kind: SectionKind,
    /// Timestamp index for dynamic sections, 0 for the static one.
    pub time_index: u32,
    pub offset: u64,
    pub length: u64,
    pub count: u64,
    pub crc32: u32,
}

impl Section {
    fn encode(&self) -> [u8; TABLE_ENTRY_LEN] {
        let mut out = [0u8; TABLE_ENTRY_LEN];
        let kind: u32 = match self.kind {
            SectionKind::Static => 0,
            SectionKind::Dynamic => 1,
        };
        out[0..4].copy_from_slice(&kind.to_le_bytes());
        out[4..8].copy_from_slice(&self.time_index.to_le_bytes());
        out[8..16].copy_from_slice(&self.offset.to_le_bytes());
        out[16..24].copy_from_slice(&self.length.to_le_bytes());
        out[24..32].copy_from_slice(&self.count.to_le_bytes());
        out[32..36].copy_from_slice(&self.crc32.to_le_bytes());
        out
    }

    fn decode(bytes: &[u8], index: usize) -> Result<Section> {
        let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
        let u64_at = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes"));
        let kind = match u32_at(0) {
            0 => SectionKind::Static,
            1 => SectionKind::Dynamic,
            other => {
                return invalid(format!(
                    "corrupt .ply4d: section {index} has unknown kind {other}"
                ))
            }
        };
        Ok(Section {
            kind,
            time_index: u32_at(4),
            offset: u64_at(8),
            length: u64_at(16),
            count: u64_at(24),
            crc32: u32_at(32),
        })
    }
}

fn extend_bounds(bounds: &mut Option<Bounds>, set: &GaussianSet) {
    for mean in &set.means {
        if !mean.iter().all(|v| v.is_finite()) {
            continue;
        }
        let b = bounds.get_or_insert(Bounds {
            min: *mean,
            max: *mean,
        });
        for (a, &v) in mean.iter().enumerate() {
            b.min[a] = b.min[a].min(v);
            b.max[a] = b.max[a].max(v);
        }
    }
}

fn align_up(v: u64) -> u64 {
    v.div_ceil(SECTION_ALIGN) * SECTION_ALIGN
}

/// Writes a `.ply4d` one set at a time, so memory stays at one set's `.ply` size and a
/// pipeline can hand over timestamps as it produces them.
///
/// Sections go to a scratch file beside `path`; [`Ply4dWriter::finish`] writes preamble,
/// header and table, copies the sections behind them (in-kernel on Linux) into a temporary
/// file, fsyncs it and renames it over `path`. An unfinished writer leaves no file behind.
pub struct Ply4dWriter {
    path: PathBuf,
    scratch_path: PathBuf,
    scratch: File,
    sh_degree: u32,
    /// Offsets relative to the start of the data area.
    sections: Vec<Section>,
    position: u64,
    bounds: Option<Bounds>,
}

impl Ply4dWriter {
    /// Starts a file whose static set (and SH degree, shared by every set) is `static_set`.
    pub fn create(path: impl AsRef<Path>, static_set: &GaussianSet) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let (_, scratch_path) = ply::temp_path_beside(&path, "sections")?;
        let scratch = OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(&scratch_path)
            .map_err(|e| FileError::io(format!("cannot write {}", path.display()), e))?;
        // Where the platform allows, the scratch file lives on only through its handle,
        // so not even a crash leaves it behind; elsewhere `Drop` removes it.
        #[cfg(unix)]
        let _ = fs::remove_file(&scratch_path);
        let mut writer = Ply4dWriter {
            path,
            scratch_path,
            scratch,
            sh_degree: static_set.sh_degree,
            sections: Vec::new(),
            position: 0,
            bounds: None,
        };
        writer.append(static_set)?;
        Ok(writer)
    }

    /// Appends the dynamic set of the next timestamp.
    pub fn push(&mut self, set: &GaussianSet) -> Result<()> {
        if set.sh_degree != self.sh_degree {
            return invalid(format!(
                "dynamic set {} has SH degree {} but the static set has {}; \
                 every set of a scene must share one degree",
                self.sections.len() - 1,
                set.sh_degree,
                self.sh_degree
            ));
        }
        self.append(set)
    }

    fn append(&mut self, set: &GaussianSet) -> Result<()> {
        let blob = ply::encode_ply(set)?;
        let offset = align_up(self.position);
        let padding = vec![0u8; (offset - self.position) as usize];
        let written = self
            .scratch
            .write_all(&padding)
            .and_then(|()| self.scratch.write_all(&blob));
        written.map_err(|e| FileError::io(format!("cannot write {}", self.path.display()), e))?;
        let time_index = self.sections.len().saturating_sub(1);
        let Ok(time_index) = u32::try_from(time_index) else {
            return invalid("a .ply4d holds at most 2^32 - 1 timestamps");
        };
        self.sections.push(Section {
            kind: if self.sections.is_empty() {
                SectionKind::Static
            } else {
                SectionKind::Dynamic
            },
            time_index,
            offset,
            length: blob.len() as u64,
            count: set.len() as u64,
            crc32: crc32fast::hash(&blob),
        });
        self.position = offset + blob.len() as u64;
        extend_bounds(&mut self.bounds, set);
        Ok(())
    }

    /// Writes the file; `meta.timestamps` must name one time per pushed dynamic set.
    pub fn finish(mut self, meta: SceneMeta) -> Result<()> {
        let num_dynamic = self.sections.len() - 1;
        if meta.timestamps.len() != num_dynamic {
            return invalid(format!(
                "scene has {} timestamps but {num_dynamic} dynamic sets",
                meta.timestamps.len()
            ));
        }
        if !meta.fps.is_finite() || meta.timestamps.iter().any(|t| !t.is_finite()) {
            return invalid("fps and timestamps must be finite numbers");
        }
        let header = Ply4dHeader {
            format_version: FORMAT_VERSION,
            sh_degree: self.sh_degree,
            bounds: self.bounds.take(),
            meta,
        };
        let json = serde_json::to_vec(&header)
            .map_err(|e| FileError::Invalid(format!("cannot encode the .ply4d header: {e}")))?;
        let Ok(json_len) = u32::try_from(json.len()) else {
            return invalid("the .ply4d header is larger than 4 GiB");
        };
        let table_end = (PREAMBLE_LEN + json.len() + self.sections.len() * TABLE_ENTRY_LEN) as u64;
        let data_start = align_up(table_end);
        let mut table = Vec::with_capacity(self.sections.len() * TABLE_ENTRY_LEN);
        for section in &self.sections {
            let placed = Section {
                offset: data_start + section.offset,
                ..*section
            };
            table.extend_from_slice(&placed.encode());
        }
        let mut header_crc = crc32fast::Hasher::new();
        header_crc.update(&json);
        header_crc.update(&table);
        let mut preamble = Vec::with_capacity(PREAMBLE_LEN);
        preamble.extend_from_slice(&MAGIC);
        preamble.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        preamble.extend_from_slice(&json_len.to_le_bytes());
        preamble.extend_from_slice(&(self.sections.len() as u32).to_le_bytes());
        preamble.extend_from_slice(&header_crc.finalize().to_le_bytes());
        preamble.resize(PREAMBLE_LEN, 0);

        let scratch = &mut self.scratch;
        let data_len = self.position;
        write_atomic(&self.path, |file| {
            file.write_all(&preamble)?;
            file.write_all(&json)?;
            file.write_all(&table)?;
            file.write_all(&vec![0u8; (data_start - table_end) as usize])?;
            scratch.seek(SeekFrom::Start(0))?;
            let copied = io::copy(&mut (&*scratch).take(data_len), file)?;
            if copied != data_len {
                return Err(io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    "the scratch file of sections is shorter than written",
                ));
            }
            Ok(())
        })
    }
}

impl Drop for Ply4dWriter {
    fn drop(&mut self) {
        // Already gone on unix (see `create`); elsewhere this is the only cleanup.
        let _ = fs::remove_file(&self.scratch_path);
    }
}

/// Writes `scene` to `path` atomically (see [`Ply4dWriter`]).
pub fn write(path: impl AsRef<Path>, scene: &Scene4d) -> Result<()> {
    if scene.meta.timestamps.len() != scene.dynamic.len() {
        return invalid(format!(
            "scene has {} timestamps but {} dynamic sets",
            scene.meta.timestamps.len(),
            scene.dynamic.len()
        ));
    }
    let mut writer = Ply4dWriter::create(path, &scene.static_set)?;
    for set in &scene.dynamic {
        writer.push(set)?;
    }
    writer.finish(scene.meta.clone())
}

enum Storage {
    Mapped(Mmap),
    Owned(Vec<u8>),
}

impl Storage {
    fn bytes(&self) -> &[u8] {
        match self {
            Storage::Mapped(m) => m,
            Storage::Owned(v) => v,
        }
    }
}

/// A validated, memory-mapped `.ply4d` file. Sections are decoded (and their CRC checked)
/// only when read.
pub struct Ply4dReader {
    storage: Storage,
    /// The file's path, named in every error a read reports (`None` for bytes in memory).
    path: Option<PathBuf>,
    header: Ply4dHeader,
    /// `sections[0]` is the static set, `sections[1 + t]` timestamp t.
    sections: Vec<Section>,
}

impl Ply4dReader {
    /// Maps `path` and validates the preamble, header and section table.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let context = |what: &str| format!("cannot {what} {}", path.display());
        let file = File::open(path).map_err(|e| FileError::io(context("open"), e))?;
        let len = file
            .metadata()
            .map_err(|e| FileError::io(context("stat"), e))?
            .len();
        let storage = if len == 0 {
            // Mapping an empty file fails on some platforms; it is invalid anyway.
            Storage::Owned(Vec::new())
        } else {
            // SAFETY: the map is read-only; a concurrent writer replaces files by rename
            // (see `write`), so the mapped inode is not modified under us.
            let map = unsafe { Mmap::map(&file) }.map_err(|e| FileError::io(context("map"), e))?;
            Storage::Mapped(map)
        };
        Self::from_storage(storage, Some(path.to_path_buf()))
    }

    /// Validates a whole file held in memory.
    pub fn from_bytes(bytes: Vec<u8>) -> Result<Self> {
        Self::from_storage(Storage::Owned(bytes), None)
    }

    fn from_storage(storage: Storage, path: Option<PathBuf>) -> Result<Self> {
        match Self::validate(storage.bytes()) {
            Ok((header, sections)) => Ok(Ply4dReader {
                storage,
                path,
                header,
                sections,
            }),
            Err(e) => Err(name_file(e, path.as_deref())),
        }
    }

    /// The header and section table of a whole file, checked (see docs/ply4d.md).
    fn validate(bytes: &[u8]) -> Result<(Ply4dHeader, Vec<Section>)> {
        let file_len = bytes.len() as u64;
        if bytes.len() < PREAMBLE_LEN {
            return invalid(format!(
                "truncated .ply4d: {} bytes, shorter than the {PREAMBLE_LEN}-byte preamble",
                bytes.len()
            ));
        }
        if bytes[..8] != MAGIC {
            return invalid("not a .ply4d file: wrong magic bytes");
        }
        let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
        let version = u32_at(8);
        if version != FORMAT_VERSION {
            return invalid(format!(
                "unsupported .ply4d version {version}: this reader supports version {FORMAT_VERSION}"
            ));
        }
        let json_len = u32_at(12) as u64;
        let section_count = u32_at(16) as u64;
        let header_crc = u32_at(20);
        let table_start = PREAMBLE_LEN as u64 + json_len;
        let table_end = table_start + section_count * TABLE_ENTRY_LEN as u64;
        if table_end > file_len {
            return invalid(format!(
                "truncated .ply4d: header and section table need {table_end} bytes, file has {file_len}"
            ));
        }
        let json = &bytes[PREAMBLE_LEN..table_start as usize];
        let table = &bytes[table_start as usize..table_end as usize];
        let mut crc = crc32fast::Hasher::new();
        crc.update(json);
        crc.update(table);
        if crc.finalize() != header_crc {
            return invalid("corrupt .ply4d: header checksum mismatch");
        }
        let header: Ply4dHeader = serde_json::from_slice(json)
            .map_err(|e| FileError::Invalid(format!("corrupt .ply4d: invalid JSON header: {e}")))?;
        if header.format_version != version {
            return invalid(format!(
                "corrupt .ply4d: JSON format_version {} differs from the preamble's {version}",
                header.format_version
            ));
        }
        let num_times = header.meta.timestamps.len() as u64;
        if section_count != num_times + 1 {
            return invalid(format!(
                "corrupt .ply4d: {section_count} sections for {num_times} timestamps (expected {})",
                num_times + 1
            ));
        }
        let sections = table
            .chunks_exact(TABLE_ENTRY_LEN)
            .enumerate()
            .map(|(i, entry)| Section::decode(entry, i))
            .collect::<Result<Vec<_>>>()?;
        for (i, s) in sections.iter().enumerate() {
            let (kind, time_index) = match i {
                0 => (SectionKind::Static, 0),
                _ => (SectionKind::Dynamic, (i - 1) as u32),
            };
            if s.kind != kind || s.time_index != time_index {
                return invalid(format!(
                    "corrupt .ply4d: section {i} is {:?} #{}, expected {kind:?} #{time_index}",
                    s.kind, s.time_index
                ));
            }
            let end = s.offset.checked_add(s.length);
            if s.offset < table_end
                || s.offset % SECTION_ALIGN != 0
                || end.is_none_or(|e| e > file_len)
            {
                return invalid(format!(
                    "corrupt .ply4d: section {i} (offset {}, length {}) lies outside the data area \
                     [{table_end}, {file_len}) or is not {SECTION_ALIGN}-byte aligned",
                    s.offset, s.length
                ));
            }
        }
        let mut by_offset: Vec<&Section> = sections.iter().collect();
        by_offset.sort_by_key(|s| s.offset);
        for pair in by_offset.windows(2) {
            if pair[0].offset + pair[0].length > pair[1].offset {
                return invalid(format!(
                    "corrupt .ply4d: sections at offsets {} and {} overlap",
                    pair[0].offset, pair[1].offset
                ));
            }
        }
        Ok((header, sections))
    }

    /// An error of this file, naming it.
    fn invalid<T>(&self, msg: String) -> Result<T> {
        Err(name_file(FileError::Invalid(msg), self.path.as_deref()))
    }

    pub fn header(&self) -> &Ply4dHeader {
        &self.header
    }

    pub fn num_times(&self) -> usize {
        self.sections.len() - 1
    }

    pub fn sections(&self) -> &[Section] {
        &self.sections
    }

    /// Raw, checksum-verified `.ply` bytes of section `index` (0 static, 1 + t dynamic).
    pub fn section_bytes(&self, index: usize) -> Result<&[u8]> {
        let Some(s) = self.sections.get(index) else {
            return self.invalid(format!(
                "section {index} out of range: the file has {}",
                self.sections.len()
            ));
        };
        let bytes = &self.storage.bytes()[s.offset as usize..(s.offset + s.length) as usize];
        if crc32fast::hash(bytes) != s.crc32 {
            let what = match s.kind {
                SectionKind::Static => "the static set".to_string(),
                SectionKind::Dynamic => format!("timestamp {}", s.time_index),
            };
            return self.invalid(format!("corrupt .ply4d: checksum mismatch in {what}"));
        }
        Ok(bytes)
    }

    fn decode_section(&self, index: usize) -> Result<GaussianSet> {
        let set = match ply::parse_ply(self.section_bytes(index)?) {
            Ok(set) => set,
            Err(e) => return self.invalid(format!("corrupt .ply4d: section {index}: {e}")),
        };
        let s = &self.sections[index];
        if set.len() as u64 != s.count || set.sh_degree != self.header.sh_degree {
            return self.invalid(format!(
                "corrupt .ply4d: section {index} holds {} Gaussians of SH degree {}, the table \
                 says {} and the header degree {}",
                set.len(),
                set.sh_degree,
                s.count,
                self.header.sh_degree
            ));
        }
        Ok(set)
    }

    fn check_time(&self, t: usize) -> Result<()> {
        if t >= self.num_times() {
            return self.invalid(format!(
                "timestamp index {t} out of range: the file has {}",
                self.num_times()
            ));
        }
        Ok(())
    }

    pub fn read_static(&self) -> Result<GaussianSet> {
        self.decode_section(0)
    }

    pub fn read_dynamic(&self, t: usize) -> Result<GaussianSet> {
        self.check_time(t)?;
        self.decode_section(1 + t)
    }

    /// The full set at timestamp `t`: static followed by dynamic.
    pub fn read_at(&self, t: usize) -> Result<GaussianSet> {
        self.check_time(t)?;
        let mut set = self.read_static()?;
        set.extend_from(&self.read_dynamic(t)?);
        Ok(set)
    }

    /// Decodes everything.
    pub fn read_scene(&self) -> Result<Scene4d> {
        Ok(Scene4d {
            static_set: self.read_static()?,
            dynamic: (0..self.num_times())
                .map(|t| self.read_dynamic(t))
                .collect::<Result<_>>()?,
            meta: self.header.meta.clone(),
        })
    }

    /// Checks every section's checksum without decoding it.
    pub fn verify(&self) -> Result<()> {
        for i in 0..self.sections.len() {
            self.section_bytes(i)?;
        }
        Ok(())
    }

    /// Writes timestamp `t` (static + dynamic) as a plain 3DGS `.ply`, atomically.
    ///
    /// Sections in the standard layout (all that [`write`] produces) are copied byte for
    /// byte under a new header; others are decoded and re-encoded.
    pub fn export_ply(&self, t: usize, path: impl AsRef<Path>) -> Result<()> {
        self.check_time(t)?;
        let blobs = [self.section_bytes(0)?, self.section_bytes(1 + t)?];
        let names = ply::standard_property_names(self.header.sh_degree);
        let mut bodies = Vec::with_capacity(2);
        let mut total = 0usize;
        for blob in blobs {
            let header = ply::parse_header(blob)?;
            let standard = match header.elements.as_slice() {
                [vertex] => {
                    vertex.name == "vertex"
                        && vertex.properties.iter().map(|p| &p.name).eq(names.iter())
                        && vertex
                            .properties
                            .iter()
                            .all(|p| p.ty == ply::ScalarType::F32)
                        && blob.len() - header.body_offset == vertex.count * vertex.stride
                }
                _ => false,
            };
            if !standard {
                return ply::write_ply(path, &self.read_at(t)?);
            }
            total += header.elements[0].count;
            bodies.push(&blob[header.body_offset..]);
        }
        let header = ply::standard_header(total, self.header.sh_degree);
        write_atomic(path.as_ref(), |file| {
            file.write_all(header.as_bytes())?;
            bodies.iter().try_for_each(|body| file.write_all(body))
        })
    }
}

/// Reads a whole `.ply4d` file.
pub fn read(path: impl AsRef<Path>) -> Result<Scene4d> {
    Ply4dReader::open(path)?.read_scene()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gaussians::sh_coeffs;
    use proptest::prelude::*;

    fn set(n: usize, degree: u32, seed: f32) -> GaussianSet {
        let k = sh_coeffs(degree);
        let v = |i: usize, j: usize| seed + i as f32 * 0.25 - j as f32 * 1.5;
        GaussianSet {
            sh_degree: degree,
            means: (0..n).map(|i| [v(i, 0), v(i, 1), v(i, 2)]).collect(),
            log_scales: (0..n).map(|i| [v(i, 3), v(i, 4), v(i, 5)]).collect(),
            quats: (0..n)
                .map(|i| [v(i, 6), v(i, 7), v(i, 8), v(i, 9)])
                .collect(),
            opacity_logits: (0..n).map(|i| v(i, 10)).collect(),
            sh: (0..n * k * 3).map(|i| v(i, 11)).collect(),
        }
    }

    fn scene(degree: u32, counts: &[usize]) -> Scene4d {
        Scene4d {
            static_set: set(5, degree, 1.0),
            dynamic: counts
                .iter()
                .enumerate()
                .map(|(t, &n)| set(n, degree, t as f32 * 10.0))
                .collect(),
            meta: SceneMeta {
                timestamps: (0..counts.len()).map(|t| t as f64 / 8.0).collect(),
                fps: 8.0,
                camera: CameraInfo {
                    position: [0.0, 0.0, 0.0],
                    params: serde_json::json!({"width": 4096, "height": 2048}),
                },
                provenance: Provenance {
                    tool_version: "0.1.0".into(),
                    config_hash: "abc".into(),
                },
                antialiased: true,
                extra: serde_json::json!({"note": "test"}),
            },
        }
    }

    fn encoded(scene: &Scene4d) -> Vec<u8> {
        let dir = std::env::temp_dir().join(format!("ply4d-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let path = dir.join(format!(
            "{}.ply4d",
            NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
        ));
        write(&path, scene).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        bytes
    }

    #[test]
    fn round_trip_and_layout() {
        for degree in 0..=3 {
            let scene = scene(degree, &[3, 0, 7]);
            let bytes = encoded(&scene);
            let reader = Ply4dReader::from_bytes(bytes.clone()).unwrap();
            reader.verify().unwrap();
            assert_eq!(reader.read_scene().unwrap(), scene);
            assert_eq!(reader.num_times(), 3);
            assert_eq!(reader.header().sh_degree, degree);
            let at2 = reader.read_at(2).unwrap();
            assert_eq!(at2.len(), 12);
            assert_eq!(at2.means[5], scene.dynamic[2].means[0]);
            for s in reader.sections() {
                assert_eq!(s.offset % SECTION_ALIGN, 0);
                // Each section is a standalone .ply.
                let blob = &bytes[s.offset as usize..(s.offset + s.length) as usize];
                assert_eq!(ply::parse_ply(blob).unwrap().len() as u64, s.count);
            }
            let b = reader.header().bounds.as_ref().unwrap();
            assert!(b.min[0] <= 1.0 && b.max[0] >= 20.0 + 1.5);
        }
    }

    #[test]
    fn export_copies_sections_into_one_ply() {
        let scene = scene(2, &[4, 6]);
        let dir = std::env::temp_dir().join(format!("ply4d-export-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let reader = Ply4dReader::from_bytes(encoded(&scene)).unwrap();
        let out = dir.join("t1.ply");
        reader.export_ply(1, &out).unwrap();
        let exported = std::fs::read(&out).unwrap();
        assert_eq!(
            exported,
            ply::encode_ply(&reader.read_at(1).unwrap()).unwrap()
        );
        assert!(reader
            .export_ply(2, &out)
            .unwrap_err()
            .to_string()
            .contains("out of range"));

        // Another writer's sections (here: an unknown property instead of `nx`) are
        // decoded and re-encoded instead of copied.
        let mut bytes = encoded(&scene);
        let table = Ply4dReader::from_bytes(bytes.clone())
            .unwrap()
            .sections()
            .to_vec();
        for s in &table {
            let blob = &mut bytes[s.offset as usize..(s.offset + s.length) as usize];
            let at = blob.windows(3).position(|w| w == b" nx").unwrap();
            blob[at + 1] = b'q';
        }
        let crcs: Vec<u32> = table
            .iter()
            .map(|s| crc32fast::hash(&bytes[s.offset as usize..(s.offset + s.length) as usize]))
            .collect();
        let bytes = with_header(&bytes, None, |t| {
            for (i, crc) in crcs.iter().enumerate() {
                let at = i * TABLE_ENTRY_LEN + 32;
                t[at..at + 4].copy_from_slice(&crc.to_le_bytes());
            }
        });
        let foreign = Ply4dReader::from_bytes(bytes).unwrap();
        foreign.export_ply(1, &out).unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), exported);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn empty_scene() {
        let mut scene = scene(0, &[]);
        scene.static_set = GaussianSet::default();
        let reader = Ply4dReader::from_bytes(encoded(&scene)).unwrap();
        assert_eq!(reader.num_times(), 0);
        assert_eq!(reader.header().bounds, None);
        assert_eq!(reader.read_scene().unwrap(), scene);
        assert!(reader
            .read_at(0)
            .unwrap_err()
            .to_string()
            .contains("out of range"));
    }

    #[test]
    fn writer_rejects_inconsistent_scenes() {
        let dir = std::env::temp_dir().join(format!("ply4d-reject-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut mixed = scene(1, &[2]);
        mixed.dynamic[0] = set(2, 0, 0.0);
        let err = write(dir.join("never-written.ply4d"), &mixed)
            .unwrap_err()
            .to_string();
        assert!(err.contains("dynamic set 0 has SH degree 0"), "{err}");
        let mut missing = scene(0, &[2]);
        missing.meta.timestamps.clear();
        let err = write(dir.join("never-written.ply4d"), &missing)
            .unwrap_err()
            .to_string();
        assert!(err.contains("1 dynamic sets"), "{err}");
        let mut nan = scene(0, &[2]);
        nan.meta.fps = f64::NAN;
        let err = write(dir.join("never-written.ply4d"), &nan)
            .unwrap_err()
            .to_string();
        assert!(err.contains("finite"), "{err}");
        // No output and no temporary or scratch file is left behind.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn streaming_writer() {
        let dir = std::env::temp_dir().join(format!("ply4d-stream-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("stream.ply4d");
        let scene = scene(3, &[2, 0, 5]);
        let mut writer = Ply4dWriter::create(&path, &scene.static_set).unwrap();
        for set in &scene.dynamic {
            writer.push(set).unwrap();
        }
        writer.finish(scene.meta.clone()).unwrap();
        assert_eq!(read(&path).unwrap(), scene);
        assert_eq!(std::fs::read(&path).unwrap(), encoded(&scene));

        // An abandoned writer leaves the old file untouched and nothing else behind.
        let mut abandoned = Ply4dWriter::create(&path, &set(9, 3, 0.0)).unwrap();
        abandoned.push(&set(4, 3, 1.0)).unwrap();
        drop(abandoned);
        assert_eq!(read(&path).unwrap(), scene);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn error_of(bytes: Vec<u8>) -> String {
        match Ply4dReader::from_bytes(bytes).and_then(|r| r.verify()) {
            Ok(()) => panic!("expected an error"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn clear_errors() {
        let good = encoded(&scene(0, &[3, 4]));
        let mut magic = good.clone();
        magic[1] = b'Q';
        assert!(error_of(magic).contains("wrong magic"));
        let mut version = good.clone();
        version[8] = 9;
        assert!(error_of(version).contains("unsupported .ply4d version 9"));
        assert!(error_of(good[..20].to_vec()).contains("truncated"));
        assert!(error_of(good[..good.len() - 3].to_vec()).contains("outside the data area"));
        let mut header = good.clone();
        header[PREAMBLE_LEN + 3] ^= 0x20;
        assert!(error_of(header).contains("header checksum"));
        let mut body = good.clone();
        let last = body.len() - 2;
        body[last] ^= 1;
        assert!(error_of(body.clone()).contains("checksum mismatch in timestamp 1"));
        // Read from a file, the errors of a section read name the file too.
        let path = std::env::temp_dir().join(format!("ply4d-errors-{}.ply4d", std::process::id()));
        std::fs::write(&path, &body).unwrap();
        let err = read(&path).unwrap_err().to_string();
        std::fs::remove_file(&path).unwrap();
        assert!(
            err.starts_with(&format!("{}: corrupt .ply4d", path.display())),
            "{err}"
        );
    }

    /// Rewrites the JSON header and/or table of a valid file and fixes the header CRC, so
    /// that the structural checks behind the checksum are reached.
    fn with_header(good: &[u8], json: Option<&[u8]>, edit_table: impl Fn(&mut [u8])) -> Vec<u8> {
        let json_len = u32::from_le_bytes(good[12..16].try_into().unwrap()) as usize;
        let count = u32::from_le_bytes(good[16..20].try_into().unwrap()) as usize;
        let old_json = &good[PREAMBLE_LEN..PREAMBLE_LEN + json_len];
        let json = json.unwrap_or(old_json);
        let mut table = good[PREAMBLE_LEN + json_len..][..count * TABLE_ENTRY_LEN].to_vec();
        edit_table(&mut table);
        let mut out = good[..PREAMBLE_LEN].to_vec();
        out[12..16].copy_from_slice(&(json.len() as u32).to_le_bytes());
        let mut crc = crc32fast::Hasher::new();
        crc.update(json);
        crc.update(&table);
        out[20..24].copy_from_slice(&crc.finalize().to_le_bytes());
        out.extend_from_slice(json);
        out.extend_from_slice(&table);
        out.extend_from_slice(&good[PREAMBLE_LEN + json_len + table.len()..]);
        out
    }

    #[test]
    fn hostile_headers() {
        let good = encoded(&scene(0, &[3, 4]));
        // Same length as the old JSON, so section offsets stay valid.
        let json_len = u32::from_le_bytes(good[12..16].try_into().unwrap()) as usize;
        let bad_json = vec![b'{'; json_len];
        assert!(
            error_of(with_header(&good, Some(&bad_json), |_| {})).contains("invalid JSON header")
        );
        let overlap = with_header(&good, None, |t| {
            let second = t[TABLE_ENTRY_LEN + 8..TABLE_ENTRY_LEN + 16].to_vec();
            t[2 * TABLE_ENTRY_LEN + 8..2 * TABLE_ENTRY_LEN + 16].copy_from_slice(&second);
        });
        assert!(error_of(overlap).contains("overlap"));
        let huge_offset = with_header(&good, None, |t| {
            t[8..16].copy_from_slice(&(u64::MAX - 63).to_le_bytes())
        });
        assert!(error_of(huge_offset).contains("outside the data area"));
        let huge_count = with_header(&good, None, |t| {
            t[24..32].copy_from_slice(&u64::MAX.to_le_bytes())
        });
        let err = Ply4dReader::from_bytes(huge_count)
            .unwrap()
            .read_static()
            .unwrap_err()
            .to_string();
        assert!(err.contains("the table says 18446744073709551615"), "{err}");
        let mut many_sections = good.clone();
        many_sections[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(error_of(many_sections).contains("truncated"));
    }

    /// Opens a damaged file and reads every section, and checks that each read either
    /// errors or yields exactly the data its table entry describes: the PLY at
    /// `[offset, offset + length)`, whose CRC is the entry's, holding the entry's count at the
    /// header's SH degree; `read_at(t)` is static ++ dynamic `t` exactly when both read.
    /// Returns `None` if the file does not open, else each section's set (`None`: an error).
    fn read_checked(bytes: &[u8]) -> Option<Vec<Option<GaussianSet>>> {
        let reader = Ply4dReader::from_bytes(bytes.to_vec()).ok()?;
        let _ = reader.verify();
        let sets: Vec<Option<GaussianSet>> = reader
            .sections()
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let read = match i {
                    0 => reader.read_static(),
                    _ => reader.read_dynamic(i - 1),
                };
                let set = read.ok()?;
                let blob = &bytes[s.offset as usize..(s.offset + s.length) as usize];
                assert_eq!(
                    crc32fast::hash(blob),
                    s.crc32,
                    "section {i}: read past a bad CRC"
                );
                assert_eq!(
                    set.len() as u64,
                    s.count,
                    "section {i}: not the table's count"
                );
                assert_eq!(
                    set.sh_degree,
                    reader.header().sh_degree,
                    "section {i}: degree"
                );
                assert_eq!(
                    set,
                    ply::parse_ply(blob).unwrap(),
                    "section {i}: not its bytes"
                );
                Some(set)
            })
            .collect();
        for t in 0..reader.num_times() {
            match (reader.read_at(t), &sets[0], &sets[1 + t]) {
                (Ok(at), Some(static_set), Some(dynamic)) => {
                    let mut expected = static_set.clone();
                    expected.extend_from(dynamic);
                    assert_eq!(at, expected, "read_at({t})");
                }
                (Ok(_), _, _) => panic!("read_at({t}) succeeded where a section failed"),
                (Err(e), Some(_), Some(_)) => panic!("read_at({t}) failed alone: {e}"),
                (Err(_), _, _) => {}
            }
        }
        Some(sets)
    }

    /// The sets of `encoded_small()`, in section order.
    fn small_sets() -> Vec<GaussianSet> {
        let scene = small_scene();
        std::iter::once(scene.static_set)
            .chain(scene.dynamic)
            .collect()
    }

    /// Sections that read are the original sets: damage that passed every check touched
    /// nothing a reader uses (padding, the preamble's reserved bytes).
    fn assert_unchanged_where_read(sets: &[Option<GaussianSet>]) {
        for (i, (set, original)) in sets.iter().zip(small_sets()).enumerate() {
            if let Some(set) = set {
                assert_eq!(
                    *set, original,
                    "section {i} read but differs from what was written"
                );
            }
        }
    }

    /// Byte range of the section table in `encoded_small()`.
    fn table_range(bytes: &[u8]) -> std::ops::Range<usize> {
        let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        let count = u32::from_le_bytes(bytes[16..20].try_into().unwrap()) as usize;
        PREAMBLE_LEN + json_len..PREAMBLE_LEN + json_len + count * TABLE_ENTRY_LEN
    }

    proptest! {
        // 5 × 1000 cases in about a second (release), so they run in CI on every test run;
        // PROPTEST_CASES=N runs N each.
        #![proptest_config(ProptestConfig::with_cases(fuzz_cases()))]

        #[test]
        fn fuzz_mutations(edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8)) {
            let mut bytes = encoded_small();
            for (at, value) in edits {
                let i = at.index(bytes.len());
                bytes[i] = value;
            }
            if let Some(sets) = read_checked(&bytes) {
                assert_unchanged_where_read(&sets);
            }
        }

        #[test]
        fn fuzz_truncation(cut in any::<prop::sample::Index>()) {
            // The last section ends the file, so every truncated file fails to open.
            let bytes = encoded_small();
            let cut = cut.index(bytes.len());
            prop_assert!(read_checked(&bytes[..cut]).is_none(), "opened at {cut} of {} bytes", bytes.len());
        }

        #[test]
        fn fuzz_random_bytes(mut bytes in proptest::collection::vec(any::<u8>(), 0..512), magic in any::<bool>()) {
            if magic && bytes.len() >= 12 {
                bytes[..8].copy_from_slice(&MAGIC);
                bytes[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
            }
            read_checked(&bytes);
        }

        #[test]
        fn fuzz_table_fields_behind_valid_crc(
            entry in 0usize..3, field in 0usize..6, value in any::<u64>(),
        ) {
            // Mutations above rarely get past the header CRC; here the CRC is recomputed.
            // A changed field must make its section fail, and nothing else may change.
            let good = encoded_small();
            let (at, width) = (entry * TABLE_ENTRY_LEN + [0, 4, 8, 16, 24, 32][field], [4, 4, 8, 8, 8, 4][field]);
            let old = good[table_range(&good)][at..at + width].to_vec();
            let new = value.to_le_bytes()[..width].to_vec();
            let bytes = with_header(&good, None, |t| t[at..at + width].copy_from_slice(&new));
            if let Some(sets) = read_checked(&bytes) {
                if old != new {
                    prop_assert!(sets[entry].is_none(), "entry {entry} field {field} changed, yet it read");
                }
                assert_unchanged_where_read(&sets);
            }
        }

        #[test]
        fn fuzz_header_and_table_bytes_behind_valid_crc(
            edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
            in_json in any::<bool>(),
        ) {
            // Byte edits in the JSON header or the table, CRC recomputed: a section whose
            // entry changed outside its reserved bytes must fail; what reads is the original.
            let good = encoded_small();
            let table = table_range(&good);
            let mut json = good[PREAMBLE_LEN..table.start].to_vec();
            let mut entries = good[table.clone()].to_vec();
            let target = if in_json { &mut json } else { &mut entries };
            for (at, value) in edits {
                let i = at.index(target.len());
                target[i] = value;
            }
            let bytes = with_header(&good, Some(&json), |t| t.copy_from_slice(&entries));
            if let Some(sets) = read_checked(&bytes) {
                for (i, set) in sets.iter().enumerate() {
                    let fields = i * TABLE_ENTRY_LEN..i * TABLE_ENTRY_LEN + 36;
                    if entries[fields.clone()] != good[table.clone()][fields] {
                        prop_assert!(set.is_none(), "entry {i} changed, yet it read");
                    }
                }
                assert_unchanged_where_read(&sets);
            }
        }
    }

    /// Cases per fuzz property: `PROPTEST_CASES` when set (a longer run), else 1000.
    fn fuzz_cases() -> u32 {
        std::env::var("PROPTEST_CASES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(1000)
    }

    fn small_scene() -> Scene4d {
        scene(1, &[2, 3])
    }

    fn encoded_small() -> Vec<u8> {
        use std::sync::OnceLock;
        static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
        BYTES.get_or_init(|| encoded(&small_scene())).clone()
    }
}
