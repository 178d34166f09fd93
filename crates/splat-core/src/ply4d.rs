//! The `.ply4d` 4D scene format (spec: docs/ply4d.md).
//!
//! ```text
//! preamble (32 B) | JSON header | section table (40 B per section) | pad | sections
//! ```
//! Every section is a complete standard 3DGS `.ply` blob starting on a 64-byte boundary:
//! section 0 is the static set shared by all timestamps, then (version 1) one dynamic set
//! per timestamp or (version 2) one spacetime set, the dynamic Gaussians with their
//! functions of time as extra vertex properties ([`crate::spacetime`]). A reader
//! memory-maps the file and touches only the sections it decodes, and hands out the dynamic
//! set of an integer timestamp for both versions (version 2's evaluated there).

use std::fs::{self, File, OpenOptions};
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use memmap2::Mmap;
use serde::{Deserialize, Serialize};

use crate::gaussians::GaussianSet;
use crate::ply::{self, write_atomic, FileError, Result};
use crate::spacetime::{SpacetimeSet, TimeModel};

pub const MAGIC: [u8; 8] = *b"\x89PLY4D\r\n";
/// The format version of a file with one dynamic set per timestamp.
pub const VERSION_PER_TIMESTAMP: u32 = 1;
/// The format version of a file with one spacetime set (its header has a `motion`).
pub const VERSION_SPACETIME: u32 = 2;
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
    /// Seconds, one per dynamic set (version 1) or per frame of the loop (version 2).
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
    /// The form of the spacetime set's functions of time: present exactly in version 2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motion: Option<TimeModel>,
    #[serde(flatten)]
    pub meta: SceneMeta,
}

/// A 4D scene as version 1 stores it: a static set shared by all timestamps and one
/// dynamic set per timestamp.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scene4d {
    pub static_set: GaussianSet,
    pub dynamic: Vec<GaussianSet>,
    pub meta: SceneMeta,
}

/// A 4D scene as version 2 stores it: a static set and one spacetime set, whose dynamic
/// Gaussians at frame `t` are `dynamic.at(t)`; `meta.timestamps` has one time per frame of
/// the loop.
#[derive(Clone, Debug, PartialEq)]
pub struct SpacetimeScene4d {
    pub static_set: GaussianSet,
    pub dynamic: SpacetimeSet,
    pub meta: SceneMeta,
}

/// Names of a version-2 dynamic section's time properties, after the standard ones
/// (docs/ply4d.md, "Version 2"): `t_centre t_log_width`, the colour terms
/// `f_dc_{c}_{cos|sin}_{h}` and the position terms `{x|y|z}_{cos|sin}_{h}`.
pub fn time_property_names(model: &TimeModel) -> Vec<String> {
    let mut names = vec!["t_centre".to_string(), "t_log_width".to_string()];
    let terms = |harmonics: u32, channels: [&'static str; 3]| {
        (1..=harmonics).flat_map(move |h| {
            ["cos", "sin"]
                .into_iter()
                .flat_map(move |wave| channels.map(|c| format!("{c}_{wave}_{h}")))
        })
    };
    names.extend(terms(
        model.colour_harmonics,
        ["f_dc_0", "f_dc_1", "f_dc_2"],
    ));
    names.extend(terms(model.position_harmonics, ["x", "y", "z"]));
    names
}

/// A spacetime set's time parameters as [`time_property_names`] orders them, one record
/// per Gaussian. `colour_terms` and `position_terms` are already in that order per Gaussian
/// (term-major, channel-minor: cos₁ r g b, sin₁ r g b, …).
fn time_columns(set: &SpacetimeSet) -> Vec<f32> {
    let (colour, position) = (
        6 * set.model.colour_harmonics as usize,
        6 * set.model.position_harmonics as usize,
    );
    let mut columns = Vec::with_capacity(set.len() * (2 + colour + position));
    for n in 0..set.len() {
        columns.extend([set.time_centre[n], set.time_log_width[n]]);
        columns.extend_from_slice(&set.colour_terms[n * colour..(n + 1) * colour]);
        columns.extend_from_slice(&set.position_terms[n * position..(n + 1) * position]);
    }
    columns
}

/// The inverse of [`time_columns`]: `columns` holds `2 + 6·(Hc + Hp)` values per Gaussian
/// of `canonical`.
fn from_time_columns(model: TimeModel, canonical: GaussianSet, columns: &[f32]) -> SpacetimeSet {
    let (colour, position) = (
        6 * model.colour_harmonics as usize,
        6 * model.position_harmonics as usize,
    );
    let n = canonical.len();
    let mut set = SpacetimeSet {
        model,
        canonical,
        time_centre: Vec::with_capacity(n),
        time_log_width: Vec::with_capacity(n),
        colour_terms: Vec::with_capacity(n * colour),
        position_terms: Vec::with_capacity(n * position),
    };
    for record in columns.chunks_exact(2 + colour + position) {
        let (time, terms) = record.split_at(2);
        set.time_centre.push(time[0]);
        set.time_log_width.push(time[1]);
        set.colour_terms.extend_from_slice(&terms[..colour]);
        set.position_terms.extend_from_slice(&terms[colour..]);
    }
    set
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

/// Grows `bounds` over boxes `(min, max)`, leaving out those with a non-finite corner.
fn extend_bounds(bounds: &mut Option<Bounds>, boxes: impl Iterator<Item = ([f32; 3], [f32; 3])>) {
    for (lo, hi) in boxes {
        if !lo.iter().chain(&hi).all(|v| v.is_finite()) {
            continue;
        }
        let b = bounds.get_or_insert(Bounds { min: lo, max: hi });
        for a in 0..3 {
            b.min[a] = b.min[a].min(lo[a]);
            b.max[a] = b.max[a].max(hi[a]);
        }
    }
}

/// Each mean of `set`, as a box of no size.
fn mean_boxes(set: &GaussianSet) -> impl Iterator<Item = ([f32; 3], [f32; 3])> + '_ {
    set.means.iter().map(|&m| (m, m))
}

/// Where each mean of `set` can go in time: the canonical mean ± Σₕ hypot(cosₕ, sinₕ) per
/// axis (|a·cos + b·sin| ≤ hypot(a, b)), so the bounds hold at every time.
fn reach_boxes(set: &SpacetimeSet) -> impl Iterator<Item = ([f32; 3], [f32; 3])> + '_ {
    let terms = 6 * set.model.position_harmonics as usize;
    set.canonical.means.iter().enumerate().map(move |(n, &m)| {
        let mut reach = [0f32; 3];
        for wave in set.position_terms[n * terms..(n + 1) * terms].chunks_exact(6) {
            for (a, r) in reach.iter_mut().enumerate() {
                *r += wave[a].hypot(wave[3 + a]);
            }
        }
        (
            std::array::from_fn(|a| m[a] - reach[a]),
            std::array::from_fn(|a| m[a] + reach[a]),
        )
    })
}

fn align_up(v: u64) -> u64 {
    v.div_ceil(SECTION_ALIGN) * SECTION_ALIGN
}

/// Writes a `.ply4d` one set at a time, so memory stays at one set's `.ply` size and a
/// pipeline can hand over timestamps as it produces them.
///
/// Version 1: the static set, then one [`Ply4dWriter::push`] per timestamp. Version 2: the
/// static set, then the one spacetime set ([`Ply4dWriter::push_spacetime`]).
///
/// Sections go to a scratch file beside `path`; [`Ply4dWriter::finish`] writes preamble,
/// header and table, copies the sections behind them (in-kernel on Linux) into a temporary
/// file, fsyncs it and renames it over `path`. An unfinished writer leaves no file behind.
pub struct Ply4dWriter {
    path: PathBuf,
    scratch_path: PathBuf,
    scratch: File,
    sh_degree: u32,
    /// The spacetime set's time model once one is pushed: the file is then version 2.
    motion: Option<TimeModel>,
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
            motion: None,
            sections: Vec::new(),
            position: 0,
            bounds: None,
        };
        writer.append(&ply::encode_ply(static_set)?, static_set.len())?;
        extend_bounds(&mut writer.bounds, mean_boxes(static_set));
        Ok(writer)
    }

    /// Appends the dynamic set of the next timestamp (version 1).
    pub fn push(&mut self, set: &GaussianSet) -> Result<()> {
        if self.motion.is_some() {
            return invalid(
                "a .ply4d with a spacetime set (version 2) has no per-timestamp dynamic sets",
            );
        }
        self.check_degree(&format!("dynamic set {}", self.sections.len() - 1), set)?;
        self.append(&ply::encode_ply(set)?, set.len())?;
        extend_bounds(&mut self.bounds, mean_boxes(set));
        Ok(())
    }

    /// Appends the one spacetime set of a version-2 file: its dynamic Gaussians at every
    /// time.
    pub fn push_spacetime(&mut self, set: &SpacetimeSet) -> Result<()> {
        if self.sections.len() > 1 {
            return invalid(
                "a .ply4d holds one spacetime set, and no per-timestamp dynamic set beside it",
            );
        }
        set.check().map_err(FileError::Invalid)?;
        self.check_degree("the spacetime set", &set.canonical)?;
        let names = time_property_names(&set.model);
        let blob = ply::encode_ply_with_extra(&set.canonical, &names, &time_columns(set))?;
        self.append(&blob, set.len())?;
        extend_bounds(&mut self.bounds, reach_boxes(set));
        self.motion = Some(set.model);
        Ok(())
    }

    fn check_degree(&self, what: &str, set: &GaussianSet) -> Result<()> {
        if set.sh_degree != self.sh_degree {
            return invalid(format!(
                "{what} has SH degree {} but the static set has {}; \
                 every set of a scene must share one degree",
                set.sh_degree, self.sh_degree
            ));
        }
        Ok(())
    }

    /// Appends one section's bytes, a `.ply` of `count` Gaussians.
    fn append(&mut self, blob: &[u8], count: usize) -> Result<()> {
        let offset = align_up(self.position);
        let padding = vec![0u8; (offset - self.position) as usize];
        let written = self
            .scratch
            .write_all(&padding)
            .and_then(|()| self.scratch.write_all(blob));
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
            count: count as u64,
            crc32: crc32fast::hash(blob),
        });
        self.position = offset + blob.len() as u64;
        Ok(())
    }

    /// Writes the file; `meta.timestamps` must name one time per pushed dynamic set
    /// (version 1) or per frame of the spacetime set's loop (version 2).
    pub fn finish(mut self, meta: SceneMeta) -> Result<()> {
        let (version, times) = match self.motion {
            None => (VERSION_PER_TIMESTAMP, self.sections.len() - 1),
            Some(model) => (VERSION_SPACETIME, model.period as usize),
        };
        if meta.timestamps.len() != times {
            return invalid(match self.motion {
                None => format!(
                    "scene has {} timestamps but {times} dynamic sets",
                    meta.timestamps.len()
                ),
                Some(_) => format!(
                    "scene has {} timestamps but its spacetime set loops over {times} frames \
                     (one timestamp per frame)",
                    meta.timestamps.len()
                ),
            });
        }
        if !meta.fps.is_finite() || meta.timestamps.iter().any(|t| !t.is_finite()) {
            return invalid("fps and timestamps must be finite numbers");
        }
        let header = Ply4dHeader {
            format_version: version,
            sh_degree: self.sh_degree,
            bounds: self.bounds.take(),
            motion: self.motion,
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
        preamble.extend_from_slice(&version.to_le_bytes());
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

/// Writes `scene` to `path` atomically as version 1 (see [`Ply4dWriter`]).
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

/// Writes `scene` to `path` atomically as version 2 (see [`Ply4dWriter`]).
pub fn write_spacetime(path: impl AsRef<Path>, scene: &SpacetimeScene4d) -> Result<()> {
    let mut writer = Ply4dWriter::create(path, &scene.static_set)?;
    writer.push_spacetime(&scene.dynamic)?;
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
    /// `sections[0]` is the static set; version 1: `sections[1 + t]` timestamp t,
    /// version 2: `sections[1]` the spacetime set.
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
        if !(VERSION_PER_TIMESTAMP..=VERSION_SPACETIME).contains(&version) {
            return invalid(format!(
                "unsupported .ply4d version {version}: this reader supports versions \
                 {VERSION_PER_TIMESTAMP} and {VERSION_SPACETIME}"
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
        let expected_sections = match (version, header.motion) {
            (VERSION_PER_TIMESTAMP, None) => num_times + 1,
            (VERSION_SPACETIME, Some(model)) => {
                if let Err(e) = model.check() {
                    return invalid(format!("corrupt .ply4d: motion: {e}"));
                }
                if num_times != u64::from(model.period) {
                    return invalid(format!(
                        "corrupt .ply4d: {num_times} timestamps for a loop of {} frames \
                         (expected one per frame)",
                        model.period
                    ));
                }
                2
            }
            (VERSION_PER_TIMESTAMP, Some(_)) => {
                return invalid("corrupt .ply4d: a version-1 header with a 'motion' (version 2's)")
            }
            _ => return invalid("corrupt .ply4d: a version-2 header without 'motion'"),
        };
        if section_count != expected_sections {
            return invalid(format!(
                "corrupt .ply4d: {section_count} sections for {num_times} timestamps of version \
                 {version} (expected {expected_sections})"
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

    /// Timestamps the scene has: dynamic sets (version 1), frames of the loop (version 2).
    pub fn num_times(&self) -> usize {
        self.header.meta.timestamps.len()
    }

    /// The section table: static, then one section per timestamp (version 1) or the one
    /// spacetime set (version 2).
    pub fn sections(&self) -> &[Section] {
        &self.sections
    }

    /// Gaussians in each timestamp's dynamic set, from the section table (nothing decoded).
    pub fn dynamic_counts(&self) -> Vec<u64> {
        match self.header.motion {
            None => self.sections[1..].iter().map(|s| s.count).collect(),
            Some(_) => vec![self.sections[1].count; self.num_times()],
        }
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
            let what = match (s.kind, self.header.motion) {
                (SectionKind::Static, _) => "the static set".to_string(),
                (SectionKind::Dynamic, None) => format!("timestamp {}", s.time_index),
                (SectionKind::Dynamic, Some(_)) => "the spacetime set".to_string(),
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
        self.check_decoded(index, &set)?;
        Ok(set)
    }

    /// That a decoded section holds the table's count at the header's degree.
    fn check_decoded(&self, index: usize, set: &GaussianSet) -> Result<()> {
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
        Ok(())
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

    /// Timestamp `t`'s dynamic set: its section (version 1), or the spacetime set
    /// evaluated at frame `t` (version 2).
    pub fn read_dynamic(&self, t: usize) -> Result<GaussianSet> {
        self.check_time(t)?;
        match self.header.motion {
            None => self.decode_section(1 + t),
            Some(_) => Ok(self.read_spacetime()?.at(t as f64)),
        }
    }

    /// The spacetime set of a version-2 file, as stored.
    pub fn read_spacetime(&self) -> Result<SpacetimeSet> {
        let Some(model) = self.header.motion else {
            return self.invalid(format!(
                "a version-{} .ply4d stores one dynamic set per timestamp, not a spacetime set \
                 (version {VERSION_SPACETIME})",
                self.header.format_version
            ));
        };
        let names = time_property_names(&model);
        let (canonical, columns) = match ply::parse_ply_with_extra(
            self.section_bytes(1)?,
            self.header.sh_degree,
            &names,
        ) {
            Ok(decoded) => decoded,
            Err(e) => {
                return self.invalid(format!(
                    "corrupt .ply4d: section 1, the spacetime set of motion {model:?}: {e}"
                ))
            }
        };
        self.check_decoded(1, &canonical)?;
        Ok(from_time_columns(model, canonical, &columns))
    }

    /// The full set at timestamp `t`: static followed by dynamic.
    pub fn read_at(&self, t: usize) -> Result<GaussianSet> {
        self.check_time(t)?;
        let mut set = self.read_static()?;
        set.extend_from(&self.read_dynamic(t)?);
        Ok(set)
    }

    /// Decodes everything: every timestamp's dynamic set (version 2: the spacetime set,
    /// decoded once, evaluated at each; [`Ply4dReader::read_spacetime`] gives it as stored).
    pub fn read_scene(&self) -> Result<Scene4d> {
        let times = 0..self.num_times();
        let dynamic = match self.header.motion {
            None => times.map(|t| self.read_dynamic(t)).collect::<Result<_>>()?,
            Some(_) => {
                let spacetime = self.read_spacetime()?;
                times.map(|t| spacetime.at(t as f64)).collect()
            }
        };
        Ok(Scene4d {
            static_set: self.read_static()?,
            dynamic,
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
    /// Version-1 sections in the standard layout (all that [`write`] produces) are copied
    /// byte for byte under a new header; others are decoded and re-encoded, and a version-2
    /// file's spacetime set is evaluated at `t`.
    pub fn export_ply(&self, t: usize, path: impl AsRef<Path>) -> Result<()> {
        self.check_time(t)?;
        if self.header.motion.is_some() {
            return ply::write_ply(path, &self.read_at(t)?);
        }
        let blobs = [self.section_bytes(0)?, self.section_bytes(1 + t)?];
        let names = ply::standard_property_names(self.header.sh_degree);
        let mut bodies = Vec::with_capacity(2);
        let mut total = 0usize;
        for blob in blobs {
            let header = ply::parse_header(blob)?;
            let standard = header.is_vertex_layout(&names) && {
                let vertex = &header.elements[0];
                vertex.count.checked_mul(vertex.stride) == Some(blob.len() - header.body_offset)
            };
            if !standard {
                return ply::write_ply(path, &self.read_at(t)?);
            }
            total += header.elements[0].count;
            bodies.push(&blob[header.body_offset..]);
        }
        let header = ply::standard_header(total, self.header.sh_degree, &[]);
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

    /// `n` spacetime Gaussians of `model` with values of every sign and size: centres in
    /// and beyond the loop, widths from a fraction of a frame to many periods.
    fn spacetime(n: usize, degree: u32, model: TimeModel, seed: f32) -> SpacetimeSet {
        let wave = |count: u32, scale: f32| -> Vec<f32> {
            (0..n * 6 * count as usize)
                .map(|i| scale * (seed + i as f32 * 0.7).sin())
                .collect()
        };
        let period = model.period as f32;
        SpacetimeSet {
            model,
            canonical: set(n, degree, seed),
            time_centre: (0..n).map(|i| (i as f32 * 0.37 - 0.5) * period).collect(),
            time_log_width: (0..n).map(|i| -2.0 + i as f32 * 0.9).collect(),
            colour_terms: wave(model.colour_harmonics, 0.3),
            position_terms: wave(model.position_harmonics, 0.2),
        }
    }

    const MODEL: TimeModel = TimeModel {
        period: 4,
        colour_harmonics: 1,
        position_harmonics: 2,
    };

    /// A version-2 scene: `scene(degree, ..)`'s static set and metadata, `n` spacetime
    /// Gaussians of `model`.
    fn spacetime_scene(degree: u32, n: usize, model: TimeModel) -> SpacetimeScene4d {
        let mut meta = scene(degree, &[]).meta;
        meta.timestamps = (0..model.period).map(|t| f64::from(t) / 8.0).collect();
        SpacetimeScene4d {
            static_set: set(5, degree, 1.0),
            dynamic: spacetime(n, degree, model, 3.0),
            meta,
        }
    }

    /// The bytes `write_to` leaves at a fresh path.
    fn written(write_to: impl FnOnce(&Path) -> Result<()>) -> Vec<u8> {
        let dir = std::env::temp_dir().join(format!("ply4d-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let path = dir.join(format!(
            "{}.ply4d",
            NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
        ));
        write_to(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        bytes
    }

    fn encoded(scene: &Scene4d) -> Vec<u8> {
        written(|path| write(path, scene))
    }

    fn encoded_spacetime(scene: &SpacetimeScene4d) -> Vec<u8> {
        written(|path| write_spacetime(path, scene))
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

    // --- version 2 ----------------------------------------------------------------------

    #[test]
    fn spacetime_round_trip_and_evaluation() {
        let models = [
            TimeModel {
                period: 1,
                colour_harmonics: 0,
                position_harmonics: 0,
            },
            MODEL,
            TimeModel {
                period: 14,
                colour_harmonics: 3,
                position_harmonics: 1,
            },
        ];
        for degree in 0..=3 {
            for model in models {
                let scene = spacetime_scene(degree, 7, model);
                let bytes = encoded_spacetime(&scene);
                let reader = Ply4dReader::from_bytes(bytes.clone()).unwrap();
                reader.verify().unwrap();
                let header = reader.header();
                assert_eq!(header.format_version, VERSION_SPACETIME);
                assert_eq!(header.motion, Some(model));
                assert_eq!(header.meta, scene.meta);
                assert_eq!(reader.num_times(), model.period as usize);
                assert_eq!(reader.sections().len(), 2);
                assert_eq!(reader.dynamic_counts(), vec![7; model.period as usize]);
                assert_eq!(reader.read_static().unwrap(), scene.static_set);
                assert_eq!(reader.read_spacetime().unwrap(), scene.dynamic);
                let whole = reader.read_scene().unwrap();
                for t in 0..reader.num_times() {
                    let at = scene.dynamic.at(t as f64);
                    assert_eq!(reader.read_dynamic(t).unwrap(), at, "t = {t}");
                    assert_eq!(whole.dynamic[t], at);
                    let mut expected = scene.static_set.clone();
                    expected.extend_from(&at);
                    assert_eq!(reader.read_at(t).unwrap(), expected);
                }
                let err = reader.read_at(reader.num_times()).unwrap_err().to_string();
                assert!(err.contains("out of range"), "{err}");
                // The dynamic section opens in any 3DGS reader as the canonical set.
                let s = reader.sections()[1];
                let blob = &bytes[s.offset as usize..(s.offset + s.length) as usize];
                assert_eq!(ply::parse_ply(blob).unwrap(), scene.dynamic.canonical);
                // The bounds hold every mean at every time, between frames too.
                let b = header.bounds.as_ref().unwrap();
                for step in 0..4 * model.period {
                    for mean in &scene.dynamic.at(f64::from(step) / 4.0).means {
                        for a in 0..3 {
                            assert!(b.min[a] <= mean[a] && mean[a] <= b.max[a], "{mean:?}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn spacetime_section_properties_are_the_specs() {
        let scene = spacetime_scene(0, 2, MODEL);
        let bytes = encoded_spacetime(&scene);
        let reader = Ply4dReader::from_bytes(bytes.clone()).unwrap();
        let s = reader.sections()[1];
        let blob = &bytes[s.offset as usize..(s.offset + s.length) as usize];
        let header = ply::parse_header(blob).unwrap();
        let vertex = &header.elements[0];
        let names: Vec<&str> = vertex.properties.iter().map(|p| p.name.as_str()).collect();
        let mut expected = ply::standard_property_names(0);
        expected.extend(
            "t_centre t_log_width \
             f_dc_0_cos_1 f_dc_1_cos_1 f_dc_2_cos_1 f_dc_0_sin_1 f_dc_1_sin_1 f_dc_2_sin_1 \
             x_cos_1 y_cos_1 z_cos_1 x_sin_1 y_sin_1 z_sin_1 \
             x_cos_2 y_cos_2 z_cos_2 x_sin_2 y_sin_2 z_sin_2"
                .split(' ')
                .map(String::from),
        );
        assert_eq!(names, expected);
        // Gaussian 1's values sit under their names.
        let value = |name: &str| {
            let p = vertex.properties.iter().find(|p| p.name == name).unwrap();
            let at = header.body_offset + vertex.stride + p.offset;
            f32::from_le_bytes(blob[at..at + 4].try_into().unwrap())
        };
        let d = &scene.dynamic;
        assert_eq!(value("t_centre"), d.time_centre[1]);
        assert_eq!(value("t_log_width"), d.time_log_width[1]);
        // colour_terms (N, 2, 3): Gaussian 1, term sin₁ (index 1), channel 2.
        assert_eq!(value("f_dc_2_sin_1"), d.colour_terms[(2 + 1) * 3 + 2]);
        // position_terms (N, 4, 3): Gaussian 1, term cos₂ (index 2), axis y.
        assert_eq!(value("y_cos_2"), d.position_terms[(4 + 2) * 3 + 1]);
    }

    #[test]
    fn spacetime_export_is_the_evaluated_scene() {
        let scene = spacetime_scene(2, 6, MODEL);
        let reader = Ply4dReader::from_bytes(encoded_spacetime(&scene)).unwrap();
        let dir = std::env::temp_dir().join(format!("ply4d-export2-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("t3.ply");
        reader.export_ply(3, &out).unwrap();
        assert_eq!(
            std::fs::read(&out).unwrap(),
            ply::encode_ply(&reader.read_at(3).unwrap()).unwrap()
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn writer_rejects_inconsistent_spacetime_scenes() {
        let dir = std::env::temp_dir().join(format!("ply4d-reject2-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("never-written.ply4d");
        let error =
            |scene: &SpacetimeScene4d| write_spacetime(&path, scene).unwrap_err().to_string();
        let mut short = spacetime_scene(1, 3, MODEL);
        short.meta.timestamps.pop();
        let err = error(&short);
        assert!(
            err.contains("3 timestamps but its spacetime set loops over 4 frames"),
            "{err}"
        );
        let mut degree = spacetime_scene(1, 3, MODEL);
        degree.dynamic = spacetime(3, 2, MODEL, 0.0);
        let err = error(&degree);
        assert!(err.contains("the spacetime set has SH degree 2"), "{err}");
        let mut ragged = spacetime_scene(1, 3, MODEL);
        ragged.dynamic.colour_terms.pop();
        assert!(error(&ragged).contains("colour_terms has 17 values, expected 18"));
        let mut harmonics = spacetime_scene(1, 3, MODEL);
        harmonics.dynamic.model.position_harmonics = 9;
        assert!(error(&harmonics).contains("position_harmonics must be 0..=8"));
        let mut nan = spacetime_scene(1, 3, MODEL);
        nan.meta.timestamps[2] = f64::INFINITY;
        assert!(error(&nan).contains("finite"));

        let scene = spacetime_scene(1, 3, MODEL);
        let mut writer = Ply4dWriter::create(&path, &scene.static_set).unwrap();
        writer.push(&set(2, 1, 0.0)).unwrap();
        let err = writer.push_spacetime(&scene.dynamic).unwrap_err();
        assert!(err
            .to_string()
            .contains("no per-timestamp dynamic set beside it"));
        let mut writer = Ply4dWriter::create(&path, &scene.static_set).unwrap();
        writer.push_spacetime(&scene.dynamic).unwrap();
        assert!(writer.push_spacetime(&scene.dynamic).is_err());
        let err = writer.push(&set(2, 1, 0.0)).unwrap_err();
        assert!(err
            .to_string()
            .contains("has no per-timestamp dynamic sets"));
        drop(writer);
        // No output and no temporary or scratch file is left behind.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_version_1_file_has_no_spacetime_set() {
        let reader = Ply4dReader::from_bytes(encoded(&scene(0, &[2]))).unwrap();
        assert_eq!(reader.header().motion, None);
        let err = reader.read_spacetime().unwrap_err().to_string();
        assert!(
            err.contains("version-1 .ply4d stores one dynamic set per timestamp"),
            "{err}"
        );
        assert_eq!(reader.dynamic_counts(), vec![2]);
    }

    /// The JSON header of `good` edited by `edit`, padded with spaces to its old length so
    /// that no section moves (for [`with_header`]).
    fn same_length_json(good: &[u8], edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
        let json_len = u32::from_le_bytes(good[12..16].try_into().unwrap()) as usize;
        let mut value: serde_json::Value =
            serde_json::from_slice(&good[PREAMBLE_LEN..PREAMBLE_LEN + json_len]).unwrap();
        edit(&mut value);
        let mut json = serde_json::to_vec(&value).unwrap();
        assert!(json.len() <= json_len, "the edited header must not grow");
        json.resize(json_len, b' ');
        json
    }

    /// `good` with its preamble's version set to `version`.
    fn with_version(mut bytes: Vec<u8>, version: u32) -> Vec<u8> {
        bytes[8..12].copy_from_slice(&version.to_le_bytes());
        bytes
    }

    #[test]
    fn hostile_spacetime_files() {
        let good = encoded_spacetime(&spacetime_scene(1, 3, MODEL));
        let header_error = |edit: fn(&mut serde_json::Value)| {
            error_of(with_header(
                &good,
                Some(&same_length_json(&good, edit)),
                |_| {},
            ))
        };
        let err = header_error(|h| h["motion"]["period"] = 0.into());
        assert!(err.contains("motion: a loop's period must be ≥ 1"), "{err}");
        let err = header_error(|h| h["motion"]["colour_harmonics"] = 9.into());
        assert!(
            err.contains("motion: colour_harmonics must be 0..=8, got 9"),
            "{err}"
        );
        let err = header_error(|h| h["motion"]["period"] = 5.into());
        assert!(err.contains("4 timestamps for a loop of 5 frames"), "{err}");
        let err = header_error(|h| {
            h["motion"]["period"] = (-1).into();
            h["extra"] = serde_json::json!({}); // room for the sign
        });
        assert!(err.contains("invalid JSON header"), "{err}");
        let err = header_error(|h| {
            h.as_object_mut().unwrap().remove("motion");
        });
        assert!(err.contains("a version-2 header without 'motion'"), "{err}");
        let err = error_of(with_version(
            with_header(
                &good,
                Some(&same_length_json(&good, |h| h["format_version"] = 1.into())),
                |_| {},
            ),
            VERSION_PER_TIMESTAMP,
        ));
        assert!(err.contains("a version-1 header with a 'motion'"), "{err}");

        // The section's properties are not those of the header's motion.
        let other_motion = with_header(
            &good,
            Some(&same_length_json(&good, |h| {
                h["motion"]["colour_harmonics"] = 2.into()
            })),
            |_| {},
        );
        let path = std::env::temp_dir().join(format!("ply4d-motion-{}.ply4d", std::process::id()));
        std::fs::write(&path, &other_motion).unwrap();
        let reader = Ply4dReader::open(&path).unwrap();
        let err = reader.read_dynamic(0).unwrap_err().to_string();
        std::fs::remove_file(&path).unwrap();
        assert!(
            err.starts_with(&format!("{}: corrupt .ply4d: section 1", path.display())),
            "{err}"
        );
        assert!(
            err.contains("f_dc_2_sin_1 f_dc_0_cos_2 f_dc_1_cos_2 f_dc_2_cos_2")
                && err.contains("got element 'vertex'"),
            "{err}"
        );

        // The table: a second section where the one spacetime set is, a time index, a
        // count, an overlap.
        let entry = TABLE_ENTRY_LEN;
        let indexed = with_header(&good, None, |t| {
            t[entry + 4..entry + 8].copy_from_slice(&1u32.to_le_bytes())
        });
        assert!(error_of(indexed).contains("section 1 is Dynamic #1, expected Dynamic #0"));
        let huge_count = with_header(&good, None, |t| {
            t[entry + 24..entry + 32].copy_from_slice(&u64::MAX.to_le_bytes())
        });
        let err = Ply4dReader::from_bytes(huge_count)
            .unwrap()
            .read_spacetime()
            .unwrap_err()
            .to_string();
        assert!(err.contains("the table says 18446744073709551615"), "{err}");
        let overlap = with_header(&good, None, |t| {
            let first = t[8..16].to_vec();
            t[entry + 8..entry + 16].copy_from_slice(&first);
        });
        assert!(error_of(overlap).contains("overlap"));
        let mut body = good.clone();
        let last = body.len() - 2;
        body[last] ^= 1;
        assert!(error_of(body).contains("checksum mismatch in the spacetime set"));
        assert!(error_of(good[..good.len() - 1].to_vec()).contains("outside the data area"));

        // A version-1 file of three sections relabelled version 2: its section count.
        let mut v1 = scene(1, &[2, 3]);
        v1.meta.extra = serde_json::json!({"room": "x".repeat(100)});
        let v1 = encoded(&v1);
        let relabelled = with_header(
            &v1,
            Some(&same_length_json(&v1, |h| {
                h["format_version"] = 2.into();
                h["motion"] = serde_json::json!({"period": 2, "colour_harmonics": 0, "position_harmonics": 0});
                h["extra"] = serde_json::json!({});
            })),
            |_| {},
        );
        let err = error_of(with_version(relabelled, VERSION_SPACETIME));
        assert!(
            err.contains("3 sections for 2 timestamps of version 2 (expected 2)"),
            "{err}"
        );
    }

    /// What one section decodes to.
    #[derive(Clone, Debug, PartialEq)]
    enum Decoded {
        Set(GaussianSet),
        Spacetime(SpacetimeSet),
    }

    impl Decoded {
        /// The Gaussians the section's `.ply` holds (a spacetime set's canonical ones).
        fn gaussians(&self) -> &GaussianSet {
            match self {
                Decoded::Set(set) => set,
                Decoded::Spacetime(set) => &set.canonical,
            }
        }
    }

    /// The largest single allocation the thread makes, tracked around a read: the fuzzers
    /// check that a damaged file never makes the reader allocate more than its size.
    mod largest_allocation {
        use std::alloc::{GlobalAlloc, Layout, System};
        use std::cell::Cell;

        thread_local! {
            static LARGEST: Cell<usize> = const { Cell::new(0) };
        }

        struct Tracking;

        fn note(size: usize) {
            // `try_with`: allocations while the thread exits find no thread-local.
            let _ = LARGEST.try_with(|largest| largest.set(largest.get().max(size)));
        }

        // SAFETY: every call forwards to the system allocator unchanged.
        unsafe impl GlobalAlloc for Tracking {
            unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
                note(layout.size());
                unsafe { System.alloc(layout) }
            }

            unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
                note(layout.size());
                unsafe { System.alloc_zeroed(layout) }
            }

            unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
                note(new_size);
                unsafe { System.realloc(ptr, layout, new_size) }
            }

            unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
                unsafe { System.dealloc(ptr, layout) }
            }
        }

        #[global_allocator]
        static TRACKING: Tracking = Tracking;

        /// `f`'s result and the largest single allocation the thread made while it ran.
        pub fn during<T>(f: impl FnOnce() -> T) -> (T, usize) {
            LARGEST.with(|largest| largest.set(0));
            let out = f();
            (out, LARGEST.with(Cell::get))
        }
    }

    /// Opens a damaged file and reads every section, and checks that each read either
    /// errors or yields exactly the data its table entry describes: the PLY at
    /// `[offset, offset + length)`, whose CRC is the entry's, holding the entry's count at the
    /// header's SH degree (version 2: the spacetime set of the header's motion);
    /// `read_at(t)` is static ++ dynamic `t` (version 2: the spacetime set at `t`) exactly
    /// when both read; and no single allocation is larger than the file (or a few KiB, for
    /// the errors' messages). Returns `None` if the file does not open, else each section's
    /// contents (`None`: an error).
    fn read_checked(bytes: &[u8]) -> Option<Vec<Option<Decoded>>> {
        let (sections, largest) = largest_allocation::during(|| read_sections_checked(bytes));
        let limit = bytes.len().max(4096);
        assert!(
            largest <= limit,
            "allocated {largest} bytes at once for a {}-byte file",
            bytes.len()
        );
        sections
    }

    fn read_sections_checked(bytes: &[u8]) -> Option<Vec<Option<Decoded>>> {
        let reader = Ply4dReader::from_bytes(bytes.to_vec()).ok()?;
        let _ = reader.verify();
        let motion = reader.header().motion;
        let sets: Vec<Option<Decoded>> = reader
            .sections()
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let read = match (i, motion) {
                    (0, _) => reader.read_static().map(Decoded::Set),
                    (_, None) => reader.read_dynamic(i - 1).map(Decoded::Set),
                    (_, Some(_)) => reader.read_spacetime().map(Decoded::Spacetime),
                };
                let decoded = read.ok()?;
                let blob = &bytes[s.offset as usize..(s.offset + s.length) as usize];
                assert_eq!(
                    crc32fast::hash(blob),
                    s.crc32,
                    "section {i}: read past a bad CRC"
                );
                let set = decoded.gaussians();
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
                let from_bytes = match &decoded {
                    Decoded::Set(_) => Decoded::Set(ply::parse_ply(blob).unwrap()),
                    Decoded::Spacetime(s) => {
                        let names = time_property_names(&s.model);
                        let (canonical, columns) =
                            ply::parse_ply_with_extra(blob, set.sh_degree, &names).unwrap();
                        Decoded::Spacetime(from_time_columns(s.model, canonical, &columns))
                    }
                };
                assert_eq!(decoded, from_bytes, "section {i}: not its bytes");
                Some(decoded)
            })
            .collect();
        for t in 0..reader.num_times() {
            let dynamic = match motion {
                None => &sets[1 + t],
                Some(_) => &sets[1],
            };
            match (reader.read_at(t), &sets[0], dynamic) {
                (Ok(at), Some(Decoded::Set(static_set)), Some(dynamic)) => {
                    let mut expected = static_set.clone();
                    expected.extend_from(&match dynamic {
                        Decoded::Set(set) => set.clone(),
                        Decoded::Spacetime(set) => set.at(t as f64),
                    });
                    assert_eq!(at, expected, "read_at({t})");
                }
                (Ok(_), _, _) => panic!("read_at({t}) succeeded where a section failed"),
                (Err(e), Some(_), Some(_)) => panic!("read_at({t}) failed alone: {e}"),
                (Err(_), _, _) => {}
            }
        }
        Some(sets)
    }

    /// Sections that read are the original contents: damage that passed every check touched
    /// nothing a reader uses (padding, the preamble's reserved bytes).
    fn assert_unchanged_where_read(sets: &[Option<Decoded>], original: &[Decoded]) {
        assert!(sets.len() <= original.len(), "more sections than written");
        for (i, (set, original)) in sets.iter().zip(original).enumerate() {
            if let Some(set) = set {
                assert_eq!(
                    set, original,
                    "section {i} read but differs from what was written"
                );
            }
        }
    }

    /// Byte range of the section table in a file whose preamble is intact.
    fn table_range(bytes: &[u8]) -> std::ops::Range<usize> {
        let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        let count = u32::from_le_bytes(bytes[16..20].try_into().unwrap()) as usize;
        PREAMBLE_LEN + json_len..PREAMBLE_LEN + json_len + count * TABLE_ENTRY_LEN
    }

    proptest! {
        // 5 × 1000 cases in about a second (release), so they run in CI on every test run;
        // PROPTEST_CASES=N runs N each. `spacetime` picks the seed file: version 2 (one
        // spacetime set) or version 1 (a set per timestamp).
        #![proptest_config(ProptestConfig::with_cases(fuzz_cases()))]

        #[test]
        fn fuzz_mutations(
            edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
            spacetime in any::<bool>(),
        ) {
            let (mut bytes, original) = small(spacetime);
            for (at, value) in edits {
                let i = at.index(bytes.len());
                bytes[i] = value;
            }
            if let Some(sets) = read_checked(&bytes) {
                assert_unchanged_where_read(&sets, &original);
            }
        }

        #[test]
        fn fuzz_truncation(cut in any::<prop::sample::Index>(), spacetime in any::<bool>()) {
            // The last section ends the file, so every truncated file fails to open.
            let (bytes, _) = small(spacetime);
            let cut = cut.index(bytes.len());
            prop_assert!(read_checked(&bytes[..cut]).is_none(), "opened at {cut} of {} bytes", bytes.len());
        }

        #[test]
        fn fuzz_random_bytes(
            mut bytes in proptest::collection::vec(any::<u8>(), 0..512),
            magic in any::<bool>(),
            spacetime in any::<bool>(),
        ) {
            if magic && bytes.len() >= 12 {
                let version = if spacetime { VERSION_SPACETIME } else { VERSION_PER_TIMESTAMP };
                bytes[..8].copy_from_slice(&MAGIC);
                bytes[8..12].copy_from_slice(&version.to_le_bytes());
            }
            read_checked(&bytes);
        }

        #[test]
        fn fuzz_table_fields_behind_valid_crc(
            entry in any::<prop::sample::Index>(), field in 0usize..6, value in any::<u64>(),
            spacetime in any::<bool>(),
        ) {
            // Mutations above rarely get past the header CRC; here the CRC is recomputed.
            // A changed field must make its section fail, and nothing else may change.
            let (good, original) = small(spacetime);
            let entry = entry.index(original.len());
            let (at, width) = (entry * TABLE_ENTRY_LEN + [0, 4, 8, 16, 24, 32][field], [4, 4, 8, 8, 8, 4][field]);
            let old = good[table_range(&good)][at..at + width].to_vec();
            let new = value.to_le_bytes()[..width].to_vec();
            let bytes = with_header(&good, None, |t| t[at..at + width].copy_from_slice(&new));
            if let Some(sets) = read_checked(&bytes) {
                if old != new {
                    prop_assert!(sets[entry].is_none(), "entry {entry} field {field} changed, yet it read");
                }
                assert_unchanged_where_read(&sets, &original);
            }
        }

        #[test]
        fn fuzz_header_and_table_bytes_behind_valid_crc(
            edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
            in_json in any::<bool>(),
            spacetime in any::<bool>(),
        ) {
            // Byte edits in the JSON header or the table, CRC recomputed: a section whose
            // entry changed outside its reserved bytes must fail; what reads is the original.
            let (good, original) = small(spacetime);
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
                assert_unchanged_where_read(&sets, &original);
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

    /// The fuzzers' seed file, version 2 (`spacetime`) or 1, and its sections' contents.
    fn small(spacetime: bool) -> (Vec<u8>, Vec<Decoded>) {
        use std::sync::OnceLock;
        type Seed = (Vec<u8>, Vec<Decoded>);
        static SEEDS: OnceLock<[Seed; 2]> = OnceLock::new();
        let [per_timestamp, spacetime_seed] = SEEDS.get_or_init(|| {
            let v1 = scene(1, &[2, 3]);
            let v2 = spacetime_scene(1, 3, MODEL);
            [
                (
                    encoded(&v1),
                    std::iter::once(v1.static_set)
                        .chain(v1.dynamic)
                        .map(Decoded::Set)
                        .collect(),
                ),
                (
                    encoded_spacetime(&v2),
                    vec![Decoded::Set(v2.static_set), Decoded::Spacetime(v2.dynamic)],
                ),
            ]
        });
        if spacetime {
            spacetime_seed
        } else {
            per_timestamp
        }
        .clone()
    }
}
