//! Standard 3DGS `.ply` files (binary little-endian) and the SuperSplat/PlayCanvas
//! `.compressed.ply` layout, read into and written from a [`GaussianSet`].
//!
//! Property names follow the Inria 3DGS code: `x y z`, optional `nx ny nz` (written as 0,
//! ignored on read), `f_dc_0..2`, `f_rest_*` channel-major (`f_rest_{c*(K-1)+(k-1)}` holds
//! `sh[k][c]`), `opacity` (logit), `scale_0..2` (log), `rot_0..3` (w, x, y, z).
//!
//! A standard file may carry extra float32 properties after the standard ones in every
//! record ([`encode_ply_with_extra`], [`parse_ply_with_extra`]): `.ply4d` version 2 stores
//! its time parameters so, and other 3DGS tools read the file and ignore them.

use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::gaussians::{sh_coeffs, GaussianSet, SH_C0};

/// Why reading or writing a Gaussian file failed.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// The operating system refused (missing file, permissions, full disk, ...).
    #[error("{context}: {source}")]
    Io {
        context: String,
        #[source]
        source: io::Error,
    },
    /// The bytes are not a valid file of the expected format.
    #[error("{0}")]
    Invalid(String),
}

impl FileError {
    pub(crate) fn io(context: impl Into<String>, source: io::Error) -> Self {
        FileError::Io {
            context: context.into(),
            source,
        }
    }
}

pub type Result<T> = std::result::Result<T, FileError>;

fn invalid<T>(msg: impl Into<String>) -> Result<T> {
    Err(FileError::Invalid(msg.into()))
}

/// Headers longer than this are rejected: real ones are a few KiB.
const MAX_HEADER_BYTES: usize = 1 << 20;

/// Scalar types a binary PLY property can have.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScalarType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl ScalarType {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    pub fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Property {
    pub name: String,
    pub ty: ScalarType,
    /// Byte offset inside one record of its element.
    pub offset: usize,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Element {
    pub name: String,
    pub count: usize,
    pub properties: Vec<Property>,
    /// Bytes per record.
    pub stride: usize,
}

impl Element {
    fn property(&self, name: &str) -> Option<&Property> {
        self.properties.iter().find(|p| p.name == name)
    }

    /// Offset of a float32 property that must exist.
    fn f32_offset(&self, name: &str) -> Result<usize> {
        match self.property(name) {
            None => invalid(format!(
                "missing required property '{name}' in element '{}'",
                self.name
            )),
            Some(p) if p.ty != ScalarType::F32 => invalid(format!(
                "property '{name}' of element '{}' is {:?}, expected float32",
                self.name, p.ty
            )),
            Some(p) => Ok(p.offset),
        }
    }
}

/// A parsed PLY header: its elements in file order and where the binary body starts.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyHeader {
    pub elements: Vec<Element>,
    pub body_offset: usize,
}

impl PlyHeader {
    pub fn element(&self, name: &str) -> Option<&Element> {
        self.elements.iter().find(|e| e.name == name)
    }

    /// Whether the file is one `vertex` element whose properties are exactly `names`, in
    /// that order, all float32.
    pub fn is_vertex_layout(&self, names: &[String]) -> bool {
        match self.elements.as_slice() {
            [vertex] => {
                vertex.name == "vertex"
                    && vertex.properties.iter().map(|p| &p.name).eq(names)
                    && vertex.properties.iter().all(|p| p.ty == ScalarType::F32)
            }
            _ => false,
        }
    }

    /// The elements and their properties, as an error shows them (types other than float32
    /// named).
    fn layout(&self) -> String {
        let element = |e: &Element| {
            let properties = e.properties.iter().map(|p| match p.ty {
                ScalarType::F32 => p.name.clone(),
                ty => format!("{} ({ty:?})", p.name),
            });
            format!(
                "element '{}': {}",
                e.name,
                properties.collect::<Vec<_>>().join(" ")
            )
        };
        let elements: Vec<String> = self.elements.iter().map(element).collect();
        match elements.as_slice() {
            [] => "no element".to_string(),
            _ => elements.join("; "),
        }
    }

    /// Byte range of each element's records in the file, checked against `file_len`.
    fn element_ranges(&self, file_len: usize) -> Result<Vec<std::ops::Range<usize>>> {
        let mut start = self.body_offset;
        let mut ranges = Vec::with_capacity(self.elements.len());
        for e in &self.elements {
            let len = e.count.checked_mul(e.stride).filter(|&l| l <= file_len);
            let end = len
                .and_then(|l| start.checked_add(l))
                .filter(|&end| end <= file_len);
            let Some(end) = end else {
                let need = (e.count as u128) * (e.stride as u128);
                return invalid(format!(
                    "truncated PLY: element '{}' needs {need} bytes ({} records of {} bytes) \
                     but only {} bytes follow",
                    e.name,
                    e.count,
                    e.stride,
                    file_len - start
                ));
            };
            ranges.push(start..end);
            start = end;
        }
        // A binary body is exactly its records. Bytes left over mean the header's counts
        // are not the file's (a damaged digit would otherwise silently drop records).
        if start != file_len {
            return invalid(format!(
                "invalid PLY: {} bytes follow the last element's records; the header's \
                 element counts ({}) do not describe this file",
                file_len - start,
                self.elements
                    .iter()
                    .map(|e| format!("{} {}", e.name, e.count))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        Ok(ranges)
    }
}

/// Parses the ASCII header of a binary little-endian PLY.
pub fn parse_header(bytes: &[u8]) -> Result<PlyHeader> {
    if !bytes.starts_with(b"ply\n") && !bytes.starts_with(b"ply\r\n") {
        return invalid("not a PLY file: it does not start with 'ply'");
    }
    let search = &bytes[..bytes.len().min(MAX_HEADER_BYTES)];
    let marker = b"end_header";
    let Some(end_pos) = search.windows(marker.len()).position(|w| w == marker) else {
        return invalid("truncated or invalid PLY: no 'end_header' line in the first 1 MiB");
    };
    let mut body_offset = end_pos + marker.len();
    if bytes[body_offset..].starts_with(b"\r\n") {
        body_offset += 2;
    } else if bytes[body_offset..].starts_with(b"\n") {
        body_offset += 1;
    } else {
        return invalid("invalid PLY: 'end_header' is not followed by a newline");
    }
    let Ok(text) = std::str::from_utf8(&bytes[..end_pos]) else {
        return invalid("invalid PLY: the header is not ASCII text");
    };

    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (line_no, line) in text.lines().enumerate().skip(1) {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", kind, _version] => format = Some(kind.to_string()),
            ["element", name, count] => {
                let Ok(count) = count.parse::<usize>() else {
                    return invalid(format!(
                        "invalid PLY header line {}: bad element count '{count}'",
                        line_no + 1
                    ));
                };
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                    stride: 0,
                });
            }
            ["property", "list", .., name] => {
                return invalid(format!(
                    "unsupported PLY layout: list property '{name}' (only scalar properties)"
                ));
            }
            ["property", ty, name] => {
                let Some(element) = elements.last_mut() else {
                    return invalid(format!(
                        "invalid PLY header: property '{name}' before any element"
                    ));
                };
                let Some(ty) = ScalarType::parse(ty) else {
                    return invalid(format!(
                        "invalid PLY header: unknown type '{ty}' of property '{name}'"
                    ));
                };
                if element.property(name).is_some() {
                    return invalid(format!("invalid PLY header: duplicate property '{name}'"));
                }
                element.properties.push(Property {
                    name: name.to_string(),
                    ty,
                    offset: element.stride,
                });
                element.stride += ty.size();
            }
            _ => {
                return invalid(format!(
                    "invalid PLY header line {}: '{}'",
                    line_no + 1,
                    line.trim()
                ));
            }
        }
    }
    match format.as_deref() {
        Some("binary_little_endian") => {}
        Some("ascii") => {
            return invalid("unsupported PLY format 'ascii': only binary_little_endian")
        }
        Some(other) => {
            return invalid(format!(
                "unsupported PLY format '{other}': only binary_little_endian"
            ))
        }
        None => return invalid("invalid PLY header: no 'format' line"),
    }
    Ok(PlyHeader {
        elements,
        body_offset,
    })
}

fn f32_at(bytes: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(bytes[at..at + 4].try_into().expect("4-byte slice"))
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4-byte slice"))
}

/// Reads a `.ply` file: standard 3DGS or SuperSplat compressed (detected by its elements).
pub fn read_ply(path: impl AsRef<Path>) -> Result<GaussianSet> {
    let path = path.as_ref();
    let bytes =
        fs::read(path).map_err(|e| FileError::io(format!("cannot read {}", path.display()), e))?;
    parse_ply(&bytes).map_err(|e| match e {
        FileError::Invalid(msg) => FileError::Invalid(format!("{}: {msg}", path.display())),
        other => other,
    })
}

/// Decodes the bytes of a `.ply` file (standard 3DGS or SuperSplat compressed). The body
/// must be exactly the records the header counts: short or long, the file is refused.
pub fn parse_ply(bytes: &[u8]) -> Result<GaussianSet> {
    let header = parse_header(bytes)?;
    let ranges = header.element_ranges(bytes.len())?;
    let is_compressed = header.element("chunk").is_some()
        && header
            .element("vertex")
            .is_some_and(|v| v.property("packed_position").is_some());
    if is_compressed {
        decode_compressed(bytes, &header, &ranges)
    } else {
        Ok(decode_standard(bytes, &header, &ranges, &[])?.0)
    }
}

/// Decodes a standard 3DGS PLY of `sh_degree` whose vertex records hold the standard
/// properties in the Inria order followed by `extra` (all float32; nothing else, in exactly
/// that order): the set, and the extra values, `extra.len()` per Gaussian, Gaussian-major.
pub fn parse_ply_with_extra(
    bytes: &[u8],
    sh_degree: u32,
    extra: &[String],
) -> Result<(GaussianSet, Vec<f32>)> {
    let header = parse_header(bytes)?;
    let mut expected = standard_property_names(sh_degree);
    expected.extend_from_slice(extra);
    if !header.is_vertex_layout(&expected) {
        return invalid(format!(
            "expected one 'vertex' element of the float32 properties '{}', got {}",
            expected.join(" "),
            header.layout()
        ));
    }
    let ranges = header.element_ranges(bytes.len())?;
    decode_standard(bytes, &header, &ranges, extra)
}

fn element_index(header: &PlyHeader, name: &str) -> Result<usize> {
    match header.elements.iter().position(|e| e.name == name) {
        Some(i) => Ok(i),
        None => invalid(format!("invalid 3DGS PLY: no '{name}' element")),
    }
}

/// Number of `f_rest_*` properties and the SH degree they imply.
fn sh_degree_for_rest(rest: usize) -> Result<u32> {
    match rest {
        0 => Ok(0),
        9 => Ok(1),
        24 => Ok(2),
        45 => Ok(3),
        n => invalid(format!(
            "invalid 3DGS PLY: {n} f_rest_* properties, expected 0, 9, 24 or 45 (SH degree 0..3)"
        )),
    }
}

fn count_rest(element: &Element) -> usize {
    element
        .properties
        .iter()
        .filter(|p| p.name.starts_with("f_rest_"))
        .count()
}

/// The Gaussians of a standard file, and the values of the `extra` vertex properties,
/// `extra.len()` per Gaussian.
fn decode_standard(
    bytes: &[u8],
    header: &PlyHeader,
    ranges: &[std::ops::Range<usize>],
    extra: &[String],
) -> Result<(GaussianSet, Vec<f32>)> {
    let vi = element_index(header, "vertex")?;
    let vertex = &header.elements[vi];
    for p in &vertex.properties {
        if p.ty != ScalarType::F32 {
            return invalid(format!(
                "unsupported 3DGS PLY layout: vertex property '{}' is {:?}, only float32 is supported",
                p.name, p.ty
            ));
        }
    }
    let sh_degree = sh_degree_for_rest(count_rest(vertex))?;
    let k = sh_coeffs(sh_degree);
    let off = |name: &str| vertex.f32_offset(name);
    let mean_off = [off("x")?, off("y")?, off("z")?];
    let scale_off = [off("scale_0")?, off("scale_1")?, off("scale_2")?];
    let rot_off = [off("rot_0")?, off("rot_1")?, off("rot_2")?, off("rot_3")?];
    let opacity_off = off("opacity")?;
    // sh_off[k * 3 + c]: offset of coefficient k, channel c.
    let mut sh_off = vec![0usize; k * 3];
    for c in 0..3 {
        sh_off[c] = off(&format!("f_dc_{c}"))?;
        for kk in 1..k {
            sh_off[kk * 3 + c] = off(&format!("f_rest_{}", c * (k - 1) + (kk - 1)))?;
        }
    }

    let n = vertex.count;
    let body = &bytes[ranges[vi].clone()];
    let mut set = GaussianSet::with_capacity(sh_degree, n);
    // Every vertex property is float32, so byte offsets are 4 × float indices; converting a
    // whole record at once avoids a bounds-checked slice per field.
    let index = |o: usize| o / 4;
    let (mean_i, scale_i, rot_i) = (
        mean_off.map(index),
        scale_off.map(index),
        rot_off.map(index),
    );
    let opacity_i = index(opacity_off);
    let sh_i: Vec<usize> = sh_off.iter().map(|&o| index(o)).collect();
    let extra_i = extra
        .iter()
        .map(|name| Ok(index(off(name)?)))
        .collect::<Result<Vec<usize>>>()?;
    // `n` records fit in the file (`element_ranges`), so this is bounded by its size.
    let mut extra_values = Vec::with_capacity(n * extra_i.len());
    let mut floats = vec![0f32; vertex.stride / 4];
    for record in body.chunks_exact(vertex.stride) {
        for (f, b) in floats.iter_mut().zip(record.chunks_exact(4)) {
            *f = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        set.means.push(mean_i.map(|i| floats[i]));
        set.log_scales.push(scale_i.map(|i| floats[i]));
        set.quats.push(rot_i.map(|i| floats[i]));
        set.opacity_logits.push(floats[opacity_i]);
        set.sh.extend(sh_i.iter().map(|&i| floats[i]));
        extra_values.extend(extra_i.iter().map(|&i| floats[i]));
    }
    Ok((set, extra_values))
}

/// Vertices per chunk in the SuperSplat compressed layout.
const COMPRESSED_CHUNK: usize = 256;

fn unorm(value: u32, bits: u32) -> f32 {
    let max = (1u32 << bits) - 1;
    (value & max) as f32 / max as f32
}

fn unpack_11_10_11(v: u32) -> [f32; 3] {
    [unorm(v >> 21, 11), unorm(v >> 11, 10), unorm(v, 11)]
}

/// Smallest-three quaternion: 2 bits name the largest component, three 10-bit others.
fn unpack_rotation(v: u32) -> [f32; 4] {
    let scale = std::f32::consts::SQRT_2;
    let a = (unorm(v >> 20, 10) - 0.5) * scale;
    let b = (unorm(v >> 10, 10) - 0.5) * scale;
    let c = (unorm(v, 10) - 0.5) * scale;
    let m = (1.0 - (a * a + b * b + c * c)).max(0.0).sqrt();
    match v >> 30 {
        0 => [m, a, b, c],
        1 => [a, m, b, c],
        2 => [a, b, m, c],
        _ => [a, b, c, m],
    }
}

fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + (b - a) * t
}

fn decode_compressed(
    bytes: &[u8],
    header: &PlyHeader,
    ranges: &[std::ops::Range<usize>],
) -> Result<GaussianSet> {
    let ci = element_index(header, "chunk")?;
    let vi = element_index(header, "vertex")?;
    let chunk = &header.elements[ci];
    let vertex = &header.elements[vi];
    let n = vertex.count;
    if chunk
        .count
        .checked_mul(COMPRESSED_CHUNK)
        .is_none_or(|c| c < n)
    {
        return invalid(format!(
            "invalid compressed PLY: {} chunks cannot cover {n} vertices ({COMPRESSED_CHUNK} per chunk)",
            chunk.count
        ));
    }
    let u32_offset = |name: &str| match vertex.property(name) {
        Some(p) if p.ty == ScalarType::U32 => Ok(p.offset),
        Some(p) => invalid(format!(
            "invalid compressed PLY: '{name}' is {:?}, expected uint32",
            p.ty
        )),
        None => invalid(format!(
            "invalid compressed PLY: missing required property '{name}'"
        )),
    };
    let [pos_o, rot_o, scale_o, color_o] = [
        "packed_position",
        "packed_rotation",
        "packed_scale",
        "packed_color",
    ];
    let (pos_o, rot_o, scale_o, color_o) = (
        u32_offset(pos_o)?,
        u32_offset(rot_o)?,
        u32_offset(scale_o)?,
        u32_offset(color_o)?,
    );
    let names = |prefix: &str, axes: [&str; 3]| axes.map(|a| format!("{prefix}{a}"));
    let offsets = |names: [String; 3]| -> Result<[usize; 3]> {
        Ok([
            chunk.f32_offset(&names[0])?,
            chunk.f32_offset(&names[1])?,
            chunk.f32_offset(&names[2])?,
        ])
    };
    let xyz = ["x", "y", "z"];
    let min_pos = offsets(names("min_", xyz))?;
    let max_pos = offsets(names("max_", xyz))?;
    let min_scale = offsets(names("min_scale_", xyz))?;
    let max_scale = offsets(names("max_scale_", xyz))?;
    // Older files carry per-chunk colour ranges; newer ones store colour in [0, 1] directly.
    let color_range = match chunk.property("min_r") {
        Some(_) => Some((
            offsets(names("min_", ["r", "g", "b"]))?,
            offsets(names("max_", ["r", "g", "b"]))?,
        )),
        None => None,
    };

    let sh_rest = match header.elements.iter().position(|e| e.name == "sh") {
        Some(si) => Some(compressed_sh(&header.elements[si], n)?.map(|offsets| (si, offsets))),
        None => None,
    }
    .flatten();
    let sh_degree = match &sh_rest {
        Some((_, offsets)) => sh_degree_for_rest(offsets.len())?,
        None => 0,
    };
    let k = sh_coeffs(sh_degree);

    let chunk_body = &bytes[ranges[ci].clone()];
    let vertex_body = &bytes[ranges[vi].clone()];
    let mut set = GaussianSet::with_capacity(sh_degree, n);
    for i in 0..n {
        let record = &vertex_body[i * vertex.stride..(i + 1) * vertex.stride];
        let c = i / COMPRESSED_CHUNK;
        let chunk_rec = &chunk_body[c * chunk.stride..(c + 1) * chunk.stride];
        let range = |lo: [usize; 3], hi: [usize; 3], t: [f32; 3]| -> [f32; 3] {
            std::array::from_fn(|a| lerp(f32_at(chunk_rec, lo[a]), f32_at(chunk_rec, hi[a]), t[a]))
        };
        set.means.push(range(
            min_pos,
            max_pos,
            unpack_11_10_11(u32_at(record, pos_o)),
        ));
        set.log_scales.push(range(
            min_scale,
            max_scale,
            unpack_11_10_11(u32_at(record, scale_o)),
        ));
        set.quats.push(unpack_rotation(u32_at(record, rot_o)));
        let packed = u32_at(record, color_o);
        let unit = [
            unorm(packed >> 24, 8),
            unorm(packed >> 16, 8),
            unorm(packed >> 8, 8),
        ];
        let rgb = match color_range {
            Some((lo, hi)) => range(lo, hi, unit),
            None => unit,
        };
        // In f64: near alpha = 1 the f32 logit is off by whole units.
        let alpha = (f64::from(packed & 0xff) / 255.0).clamp(1e-6, 1.0 - 1e-6);
        set.opacity_logits.push((alpha / (1.0 - alpha)).ln() as f32);
        let start = set.sh.len();
        set.sh.extend(rgb.map(|v| (v - 0.5) / SH_C0));
        set.sh.resize(start + k * 3, 0.0);
        if let Some((si, offsets)) = &sh_rest {
            let sh_el = &header.elements[*si];
            let sh_rec = &bytes[ranges[*si].start + i * sh_el.stride..][..sh_el.stride];
            for kk in 1..k {
                for ch in 0..3 {
                    let byte = sh_rec[offsets[ch * (k - 1) + (kk - 1)]];
                    set.sh[start + kk * 3 + ch] = unpack_sh_byte(byte);
                }
            }
        }
    }
    Ok(set)
}

/// SuperSplat quantises each higher-order SH coefficient to 8 bits over [-4, 4].
fn unpack_sh_byte(v: u8) -> f32 {
    let t = match v {
        0 => 0.0,
        255 => 1.0,
        v => (v as f32 + 0.5) / 256.0,
    };
    (t - 0.5) * 8.0
}

/// Offsets of `f_rest_0..R-1` (uint8) in the compressed `sh` element, in index order.
fn compressed_sh(sh: &Element, n: usize) -> Result<Option<Vec<usize>>> {
    if sh.count != n {
        return invalid(format!(
            "invalid compressed PLY: 'sh' has {} records for {n} vertices",
            sh.count
        ));
    }
    let rest = count_rest(sh);
    sh_degree_for_rest(rest)?;
    let mut offsets = Vec::with_capacity(rest);
    for i in 0..rest {
        let name = format!("f_rest_{i}");
        match sh.property(&name) {
            Some(p) if p.ty == ScalarType::U8 => offsets.push(p.offset),
            Some(p) => {
                return invalid(format!(
                    "invalid compressed PLY: '{name}' is {:?}, expected uint8",
                    p.ty
                ))
            }
            None => {
                return invalid(format!(
                    "invalid compressed PLY: missing property '{name}' in 'sh'"
                ))
            }
        }
    }
    Ok(if rest == 0 { None } else { Some(offsets) })
}

/// Property names of a standard 3DGS vertex record for `sh_degree`, in file order.
pub fn standard_property_names(sh_degree: u32) -> Vec<String> {
    let k = sh_coeffs(sh_degree);
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .map(String::from)
    .to_vec();
    names.extend((0..3 * (k - 1)).map(|i| format!("f_rest_{i}")));
    names.extend(
        [
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
        ]
        .map(String::from),
    );
    names
}

/// Header text of a standard 3DGS PLY with `n` vertices whose records end in the float32
/// properties `extra`.
pub(crate) fn standard_header(n: usize, sh_degree: u32, extra: &[String]) -> String {
    let mut header = format!("ply\nformat binary_little_endian 1.0\nelement vertex {n}\n");
    for name in standard_property_names(sh_degree).iter().chain(extra) {
        header.push_str("property float ");
        header.push_str(name);
        header.push('\n');
    }
    header.push_str("end_header\n");
    header
}

/// Encodes `set` as a standard 3DGS binary PLY.
pub fn encode_ply(set: &GaussianSet) -> Result<Vec<u8>> {
    encode_ply_with_extra(set, &[], &[])
}

/// Encodes `set` as a standard 3DGS binary PLY whose records end in the float32 properties
/// `extra`, with `values` holding `extra.len()` per Gaussian, Gaussian-major.
pub fn encode_ply_with_extra(
    set: &GaussianSet,
    extra: &[String],
    values: &[f32],
) -> Result<Vec<u8>> {
    set.validate().map_err(FileError::Invalid)?;
    if values.len() != set.len() * extra.len() {
        return invalid(format!(
            "{} extra values for {} Gaussians of {} extra properties",
            values.len(),
            set.len(),
            extra.len()
        ));
    }
    let k = sh_coeffs(set.sh_degree);
    let header = standard_header(set.len(), set.sh_degree, extra);
    let floats_per_record = 14 + 3 * k + extra.len();
    let mut out = Vec::with_capacity(header.len() + set.len() * floats_per_record * 4);
    out.extend_from_slice(header.as_bytes());
    let mut record = Vec::with_capacity(floats_per_record);
    for i in 0..set.len() {
        record.clear();
        record.extend_from_slice(&set.means[i]);
        record.extend_from_slice(&[0.0; 3]);
        let sh = &set.sh[i * k * 3..(i + 1) * k * 3];
        record.extend_from_slice(&sh[..3]);
        for c in 0..3 {
            record.extend((1..k).map(|kk| sh[kk * 3 + c]));
        }
        record.push(set.opacity_logits[i]);
        record.extend_from_slice(&set.log_scales[i]);
        record.extend_from_slice(&set.quats[i]);
        record.extend_from_slice(&values[i * extra.len()..(i + 1) * extra.len()]);
        for v in &record {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    Ok(out)
}

/// Writes `set` as a standard 3DGS binary PLY, atomically.
pub fn write_ply(path: impl AsRef<Path>, set: &GaussianSet) -> Result<()> {
    let bytes = encode_ply(set)?;
    write_atomic(path.as_ref(), |file| file.write_all(&bytes))
}

/// A fresh temporary path in the folder of `path` (so that a rename onto `path` is atomic),
/// and that folder.
pub(crate) fn temp_path_beside(path: &Path, purpose: &str) -> Result<(PathBuf, PathBuf)> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let Some(name) = path.file_name() else {
        return invalid(format!(
            "cannot write to {}: not a file path",
            path.display()
        ));
    };
    let tmp = dir.join(format!(
        ".{}.{purpose}-{}-{}",
        name.to_string_lossy(),
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    Ok((dir, tmp))
}

/// Writes a file through `fill` into a temporary file in the same folder, fsyncs it and
/// renames it over `path`, so readers never see a half-written file.
pub fn write_atomic(path: &Path, fill: impl FnOnce(&mut File) -> io::Result<()>) -> Result<()> {
    let (dir, tmp) = temp_path_beside(path, "tmp")?;
    let result = (|| {
        let mut file = File::create(&tmp)?;
        fill(&mut file)?;
        file.sync_all()?;
        drop(file);
        fs::rename(&tmp, path)?;
        // Make the rename itself durable; some platforms cannot open folders, so best effort.
        if let Ok(folder) = File::open(&dir) {
            let _ = folder.sync_all();
        }
        Ok(())
    })();
    if let Err(e) = result {
        // Best effort: the temporary file is garbage either way.
        let _ = fs::remove_file(&tmp);
        return Err(FileError::io(format!("cannot write {}", path.display()), e));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn data_dir() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data")
    }

    pub(crate) fn random_set(n: usize, sh_degree: u32, seed: u32) -> GaussianSet {
        let mut state = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state as f32 / u32::MAX as f32) * 4.0 - 2.0
        };
        let k = sh_coeffs(sh_degree);
        GaussianSet {
            sh_degree,
            means: (0..n).map(|_| [next(), next(), next()]).collect(),
            log_scales: (0..n).map(|_| [next(), next(), next()]).collect(),
            quats: (0..n).map(|_| [next(), next(), next(), next()]).collect(),
            opacity_logits: (0..n).map(|_| next()).collect(),
            sh: (0..n * k * 3).map(|_| next()).collect(),
        }
    }

    fn bits(set: &GaussianSet) -> Vec<u32> {
        let mut v: Vec<u32> = Vec::new();
        v.extend(set.means.iter().flatten().map(|f| f.to_bits()));
        v.extend(set.log_scales.iter().flatten().map(|f| f.to_bits()));
        v.extend(set.quats.iter().flatten().map(|f| f.to_bits()));
        v.extend(set.opacity_logits.iter().map(|f| f.to_bits()));
        v.extend(set.sh.iter().map(|f| f.to_bits()));
        v
    }

    #[test]
    fn round_trip_every_degree_and_empty() {
        for degree in 0..=3 {
            for n in [0, 1, 7] {
                let set = random_set(n, degree, degree * 10 + n as u32);
                let back = parse_ply(&encode_ply(&set).unwrap()).unwrap();
                assert_eq!(back.sh_degree, degree);
                assert_eq!(bits(&back), bits(&set));
            }
        }
    }

    #[test]
    fn channel_major_f_rest_order() {
        let mut set = random_set(1, 1, 3);
        // sh[k][c] = 10 k + c, so f_rest_{c*3+(k-1)} must read 10 k + c.
        for kk in 0..4 {
            for c in 0..3 {
                set.sh[kk * 3 + c] = (10 * kk + c) as f32;
            }
        }
        let bytes = encode_ply(&set).unwrap();
        let header = parse_header(&bytes).unwrap();
        let v = header.element("vertex").unwrap();
        let record = &bytes[header.body_offset..];
        let rest = |i: usize| f32_at(record, v.property(&format!("f_rest_{i}")).unwrap().offset);
        assert_eq!(rest(0), 10.0); // k=1, c=0
        assert_eq!(rest(1), 20.0); // k=2, c=0
        assert_eq!(rest(3), 11.0); // k=1, c=1
        assert_eq!(rest(8), 32.0); // k=3, c=2
    }

    #[test]
    fn extra_properties_round_trip_and_must_match_exactly() {
        let extra: Vec<String> = ["t_centre", "t_log_width"].map(String::from).to_vec();
        for (n, degree) in [(0, 1), (5, 0), (9, 3)] {
            let set = random_set(n, degree, 7 + n as u32);
            let values: Vec<f32> = (0..2 * n).map(|i| i as f32 - 0.5).collect();
            let bytes = encode_ply_with_extra(&set, &extra, &values).unwrap();
            let (back, back_values) = parse_ply_with_extra(&bytes, degree, &extra).unwrap();
            assert_eq!(bits(&back), bits(&set));
            assert_eq!(back_values, values);
            // Any 3DGS reader reads the set and ignores the extra properties.
            assert_eq!(bits(&parse_ply(&bytes).unwrap()), bits(&set));
            // Another list of extra properties, or another degree, is not this layout.
            let err = parse_ply_with_extra(&bytes, degree, &extra[..1])
                .unwrap_err()
                .to_string();
            assert!(err.contains("expected one 'vertex' element of the float32 properties 'x y z"));
            assert!(err.ends_with("rot_3 t_centre t_log_width"), "{err}");
            assert!(parse_ply_with_extra(&bytes, (degree + 1) % 4, &extra).is_err());
        }
        let plain = encode_ply(&random_set(2, 0, 1)).unwrap();
        let err = parse_ply_with_extra(&plain, 0, &extra)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("properties '")
                && err.contains("t_log_width', got element 'vertex': x y z nx"),
            "{err}"
        );
        let set = random_set(2, 0, 1);
        assert!(encode_ply_with_extra(&set, &extra, &[0.0; 3])
            .unwrap_err()
            .to_string()
            .contains("3 extra values for 2 Gaussians of 2 extra properties"));
    }

    /// Builds a PLY with the given header property lines and raw f32 records.
    fn custom_ply(format: &str, props: &[&str], records: &[Vec<f32>]) -> Vec<u8> {
        let mut text = format!(
            "ply\nformat {format} 1.0\nelement vertex {}\n",
            records.len()
        );
        for p in props {
            text.push_str(&format!("property float {p}\n"));
        }
        text.push_str("end_header\n");
        let mut out = text.into_bytes();
        for r in records {
            for v in r {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }

    const MINIMAL: [&str; 14] = [
        "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
        "rot_0", "rot_1", "rot_2", "rot_3",
    ];

    #[test]
    fn any_order_and_unknown_properties() {
        let mut props: Vec<&str> = MINIMAL.iter().rev().copied().collect();
        props.insert(3, "custom_weight");
        let record: Vec<f32> = (0..props.len()).map(|i| i as f32).collect();
        let set = parse_ply(&custom_ply("binary_little_endian", &props, &[record])).unwrap();
        let value = |name: &str| props.iter().position(|p| *p == name).unwrap() as f32;
        assert_eq!(set.means[0], [value("x"), value("y"), value("z")]);
        assert_eq!(
            set.quats[0],
            [
                value("rot_0"),
                value("rot_1"),
                value("rot_2"),
                value("rot_3")
            ]
        );
        assert_eq!(set.opacity_logits[0], value("opacity"));
        assert_eq!(
            set.sh,
            vec![value("f_dc_0"), value("f_dc_1"), value("f_dc_2")]
        );
    }

    fn error_of(bytes: &[u8]) -> String {
        parse_ply(bytes).unwrap_err().to_string()
    }

    #[test]
    fn clear_errors() {
        let record = vec![0.0f32; 14];
        assert!(error_of(&custom_ply("ascii", &MINIMAL, &[])).contains("ascii"));
        assert!(
            error_of(&custom_ply("binary_big_endian", &MINIMAL, &[])).contains("binary_big_endian")
        );
        assert!(error_of(&custom_ply(
            "binary_little_endian",
            &MINIMAL[1..],
            &[record[1..].to_vec()]
        ))
        .contains("missing required property 'x'"));
        let full = custom_ply("binary_little_endian", &MINIMAL, &[record]);
        assert!(error_of(&full[..full.len() - 1]).contains("truncated"));
        let long = [&full[..], &[0]].concat();
        assert!(error_of(&long).contains("1 bytes follow the last element's records"));
        assert!(error_of(b"PK\x03\x04").contains("not a PLY file"));
        let double = String::from_utf8(custom_ply("binary_little_endian", &MINIMAL, &[]))
            .unwrap()
            .replace("property float opacity", "property double opacity");
        assert!(error_of(double.as_bytes()).contains("'opacity' is F64"));
        let huge = String::from_utf8(custom_ply("binary_little_endian", &MINIMAL, &[]))
            .unwrap()
            .replace("element vertex 0", "element vertex 18446744073709551615");
        assert!(error_of(huge.as_bytes()).contains("truncated"));
        let rest5 = custom_ply(
            "binary_little_endian",
            &[
                &MINIMAL[..],
                &["f_rest_0", "f_rest_1", "f_rest_2", "f_rest_3", "f_rest_4"],
            ]
            .concat(),
            &[],
        );
        assert!(error_of(&rest5).contains("5 f_rest_* properties"));
    }

    #[test]
    fn reads_train1000() {
        let set = read_ply(data_dir().join("gs_train1000.ply")).unwrap();
        assert_eq!((set.len(), set.sh_degree), (1000, 3));
        let norms: Vec<f32> = set
            .quats
            .iter()
            .map(|q| q.iter().map(|v| v * v).sum::<f32>().sqrt())
            .collect();
        let (lo, hi) = norms
            .iter()
            .fold((f32::MAX, f32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        assert!(
            lo < 0.7 && hi > 1.3,
            "quaternions must stay unnormalised: |q| in [{lo}, {hi}]"
        );
        // Writing it back and reading again is bit-exact.
        let back = parse_ply(&encode_ply(&set).unwrap()).unwrap();
        assert_eq!(bits(&back), bits(&set));
    }

    #[test]
    fn compressed_guitar_matches_decoded_guitar() {
        let compressed = read_ply(data_dir().join("gs_guitar.compressed.ply")).unwrap();
        let plain = read_ply(data_dir().join("gs_guitar.ply")).unwrap();
        assert_eq!((compressed.len(), compressed.sh_degree), (90_854, 0));
        assert_eq!(plain.len(), compressed.len());
        for i in 0..plain.len() {
            for a in 0..3 {
                assert!(
                    (compressed.means[i][a] - plain.means[i][a]).abs() < 1e-4,
                    "mean {i}"
                );
                assert!(
                    (compressed.log_scales[i][a] - plain.log_scales[i][a]).abs() < 1e-4,
                    "scale {i}"
                );
                assert!(
                    (compressed.sh[i * 3 + a] - plain.sh[i * 3 + a]).abs() < 1e-4,
                    "colour {i}"
                );
            }
            for a in 0..4 {
                assert!(
                    (compressed.quats[i][a] - plain.quats[i][a]).abs() < 1e-4,
                    "rotation {i}"
                );
            }
            assert!(
                (compressed.opacity_logits[i] - plain.opacity_logits[i]).abs() < 1e-3,
                "opacity {i}"
            );
        }
    }

    /// A compressed PLY with one chunk, one vertex and a degree-1 `sh` element.
    fn compressed_sample() -> Vec<u8> {
        let mut text = String::from("ply\nformat binary_little_endian 1.0\nelement chunk 1\n");
        for p in [
            "min_x",
            "min_y",
            "min_z",
            "max_x",
            "max_y",
            "max_z",
            "min_scale_x",
            "min_scale_y",
            "min_scale_z",
            "max_scale_x",
            "max_scale_y",
            "max_scale_z",
        ] {
            text.push_str(&format!("property float {p}\n"));
        }
        text.push_str("element vertex 1\n");
        for p in [
            "packed_position",
            "packed_rotation",
            "packed_scale",
            "packed_color",
        ] {
            text.push_str(&format!("property uint {p}\n"));
        }
        text.push_str("element sh 1\n");
        for i in 0..9 {
            text.push_str(&format!("property uchar f_rest_{i}\n"));
        }
        text.push_str("end_header\n");
        let mut bytes = text.into_bytes();
        for v in [
            0.0f32, 0.0, 0.0, 2.0, 2.0, 2.0, -1.0, -1.0, -1.0, 1.0, 1.0, 1.0,
        ] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        let position = (2047u32 << 21) | 1023; // y bits are 0
        let rotation = (511u32 << 20) | (511 << 10) | 511; // top bits 0: largest is w
        for v in [position, rotation, 0, 0xff00_80ff] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        bytes.extend_from_slice(&[0, 255, 128, 0, 0, 0, 0, 0, 0]);
        bytes
    }

    #[test]
    fn compressed_sh_element() {
        let bytes = compressed_sample();
        let set = parse_ply(&bytes).unwrap();
        assert_eq!(set.sh_degree, 1);
        assert_eq!(set.means[0][0], 2.0);
        assert_eq!(set.means[0][1], 0.0);
        assert!((set.means[0][2] - 1023.0 / 2047.0 * 2.0).abs() < 1e-6);
        assert!((set.quats[0][0] - 1.0).abs() < 1e-2);
        // Red 1.0 without a colour range is f_dc = 0.5 / C0.
        assert!((set.sh[0] - 0.5 / SH_C0).abs() < 1e-5);
        // f_rest_0 (k=1, c=0) = 0 -> -4; f_rest_1 (k=2, c=0) = 255 -> 4.
        assert_eq!(set.sh[3], -4.0);
        assert_eq!(set.sh[6], 4.0);
    }

    /// The small standard and compressed samples the damage tests start from.
    fn samples() -> [Vec<u8>; 2] {
        [
            encode_ply(&random_set(3, 1, 9)).unwrap(),
            compressed_sample(),
        ]
    }

    /// A damaged file parses to an error or to exactly as many Gaussians as the original:
    /// the count is never silently wrong. Returns the set when it parsed.
    fn parse_checked(bytes: &[u8], original: &GaussianSet) -> Option<GaussianSet> {
        let set = parse_ply(bytes).ok()?;
        assert_eq!(set.len(), original.len(), "parsed with a wrong count");
        Some(set)
    }

    #[test]
    fn every_truncation_fails() {
        for bytes in samples() {
            for cut in 0..bytes.len() {
                assert!(
                    parse_ply(&bytes[..cut]).is_err(),
                    "parsed at {cut} of {}",
                    bytes.len()
                );
            }
        }
    }

    /// Bits of everything but the higher-order SH: a header edit can rename an element or
    /// property to one a reader ignores (the SuperSplat `sh` element, say), which drops the
    /// higher orders from a file that is still valid.
    fn base_bits(set: &GaussianSet) -> Vec<u32> {
        let k = sh_coeffs(set.sh_degree);
        let dc = (0..set.len()).flat_map(|i| set.sh[i * k * 3..i * k * 3 + 3].to_vec());
        let mut v = bits(&GaussianSet {
            sh_degree: 0,
            sh: dc.collect(),
            ..set.clone()
        });
        v.push(set.len() as u32);
        v
    }

    #[test]
    fn every_single_byte_change_in_the_header_fails_or_changes_nothing() {
        // Exhaustive over header positions, with the values a damaged header plausibly
        // holds there (digits, separators, NUL, 0xff, the neighbouring letters and case).
        // What parses must be the original Gaussians, bit for bit: a count edited from 3
        // to 2, say, must not leave one record unread.
        for bytes in samples() {
            let original = parse_ply(&bytes).unwrap();
            let body = parse_header(&bytes).unwrap().body_offset;
            for at in 0..body {
                let b = bytes[at];
                let values = (b'0'..=b'9').chain([
                    b' ',
                    b'\n',
                    b'\r',
                    b'\t',
                    0,
                    0xff,
                    b ^ 0x20,
                    b.wrapping_add(1),
                    b.wrapping_sub(1),
                ]);
                for value in values.filter(|&v| v != b) {
                    let mut damaged = bytes.clone();
                    damaged[at] = value;
                    if let Some(set) = parse_checked(&damaged, &original) {
                        let what = format!("byte {at} = {value:#04x}");
                        assert_eq!(base_bits(&set), base_bits(&original), "{what}");
                    }
                }
            }
        }
    }

    proptest! {
        // 2 × 1000 cases in 1–2 s (mostly spent generating header text); PROPTEST_CASES=N
        // runs N each.
        #![proptest_config(ProptestConfig::with_cases(fuzz_cases()))]

        /// Damaged standard or compressed files give an error or the original count, never
        /// a panic.
        #[test]
        fn fuzz_parse_never_panics(
            compressed in any::<bool>(),
            edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..6),
            cut in any::<prop::sample::Index>(),
        ) {
            let [standard, packed] = samples();
            let mut bytes = if compressed { packed } else { standard };
            let original = parse_ply(&bytes).unwrap();
            for (at, value) in edits {
                let i = at.index(bytes.len());
                bytes[i] = value;
            }
            let keep = cut.index(bytes.len() + 1);
            parse_checked(&bytes[..keep], &original);
        }

        #[test]
        fn fuzz_header_text_never_panics(
            lines in proptest::collection::vec(
                "element (vertex|chunk|sh) [0-9]{1,3}|property (float|uint|uchar|double) \
                 (x|y|z|opacity|f_dc_[0-2]|f_rest_[0-9]|scale_[0-2]|rot_[0-3]|packed_position|min_x)\
                 |property list uchar int vertex_indices|comment [a-z ]{0,8}|[a-z_0-9 ]{0,16}",
                0..24,
            ),
            body in proptest::collection::vec(any::<u8>(), 0..256),
        ) {
            let text = format!("ply\nformat binary_little_endian 1.0\n{}\nend_header\n", lines.join("\n"));
            let _ = parse_ply(&[text.as_bytes(), &body].concat());
        }
    }

    /// Cases per fuzz property: `PROPTEST_CASES` when set (a longer run), else 1000.
    fn fuzz_cases() -> u32 {
        std::env::var("PROPTEST_CASES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(1000)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        #[test]
        fn random_floats_round_trip_bit_exact(
            degree in 0u32..=3,
            values in proptest::collection::vec(proptest::num::f32::ANY, 0..400),
        ) {
            let k = sh_coeffs(degree);
            let per = crate::gaussians::BASE_FLOATS + 3 * k;
            let n = values.len() / per;
            // ANY includes infinities, subnormals and quiet NaNs; every bit pattern must survive.
            let v = |i: usize, j: usize| values[i * per + j];
            let set = GaussianSet {
                sh_degree: degree,
                means: (0..n).map(|i| [v(i, 0), v(i, 1), v(i, 2)]).collect(),
                log_scales: (0..n).map(|i| [v(i, 3), v(i, 4), v(i, 5)]).collect(),
                quats: (0..n).map(|i| [v(i, 6), v(i, 7), v(i, 8), v(i, 9)]).collect(),
                opacity_logits: (0..n).map(|i| v(i, 10)).collect(),
                sh: (0..n).flat_map(|i| (11..per).map(move |j| v(i, j))).collect(),
            };
            let back = parse_ply(&encode_ply(&set).unwrap()).unwrap();
            prop_assert_eq!(bits(&back), bits(&set));
        }
    }
}
