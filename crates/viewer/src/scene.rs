//! What the viewer opens: a `.ply4d` 4D scene (memory-mapped; the static set is decoded
//! once; version 1: each dynamic set when its timestamp is shown; version 2: the one
//! spacetime set, once, for the GPU to evaluate), a plain 3DGS `.ply` (one static set), or a
//! folder of per-frame `.ply` files (a sequence, one dynamic set per file).
//!
//! The format is recognised by the file's first bytes, not its name, so a misnamed file
//! gets a clear message instead of a parse error deep in the wrong reader.

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use splat_core::gaussians::GaussianSet;
use splat_core::ply::{self, FileError};
use splat_core::ply4d::{self, Ply4dReader};
use splat_core::spacetime::{SpacetimeSet, TimeModel};

use crate::camera::SceneExtent;
use crate::time::Timeline;

/// Frame rate given to a folder of `.ply` files, which records none.
pub const SEQUENCE_FPS: f64 = 30.0;
/// Means looked at to estimate the scene's extent.
const EXTENT_SAMPLES: usize = 200_000;
/// How far into a `.ply` its header may reach (as far as `ply::parse_header` looks).
const HEADER_BYTES: u64 = 1 << 20;

enum Source {
    Ply4d(Box<Ply4dReader>),
    /// A single `.ply`: everything is static.
    Ply,
    /// Sorted per-frame files.
    Sequence(Vec<PathBuf>),
}

/// An opened scene. The static set is held in memory; dynamic sets are read on demand.
pub struct Scene {
    source: Source,
    /// Shown in the title and the info panel.
    pub name: String,
    /// Seconds, one per timestamp (a single 0 for a static `.ply`).
    pub timestamps: Vec<f64>,
    pub static_set: GaussianSet,
    /// SH degree of the static set (and, in a `.ply4d`, of every set).
    pub sh_degree: u32,
    pub extent: SceneExtent,
    /// Whether the scene is drawn with the rasteriser's antialiased mode (Mip-Splatting's
    /// 2D filter, `RenderSettings::antialiased`) rather than the classic one: the mode it
    /// was trained in, which its `.ply4d` header records. Drawn in the other mode, a scene
    /// looks wrong (too thin or too blurry), so this is the file's fact, not a choice. A
    /// plain `.ply` records nothing and is classic, as every other 3DGS viewer draws it.
    pub antialiased: bool,
}

fn describe(error: FileError) -> String {
    error.to_string()
}

/// What the first bytes of `path` say it is.
#[derive(Debug, PartialEq, Eq)]
enum Kind {
    Ply4d,
    Ply,
}

fn sniff(path: &Path) -> Result<Kind, String> {
    let mut head = [0u8; 8];
    let mut file = File::open(path).map_err(|e| format!("cannot open {}: {e}", path.display()))?;
    let mut filled = 0;
    while filled < head.len() {
        match file.read(&mut head[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) => return Err(format!("cannot read {}: {e}", path.display())),
        }
    }
    let head = &head[..filled];
    if head == ply4d::MAGIC {
        Ok(Kind::Ply4d)
    } else if head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n") {
        Ok(Kind::Ply)
    } else if filled == 0 {
        Err(format!("{} is empty", path.display()))
    } else {
        Err(format!(
            "{} is neither a .ply4d scene nor a 3DGS .ply file (it starts with \"{}\")",
            path.display(),
            head.escape_ascii()
        ))
    }
}

fn sequence_frames(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let entries =
        std::fs::read_dir(dir).map_err(|e| format!("cannot list {}: {e}", dir.display()))?;
    let mut frames = Vec::new();
    for entry in entries {
        let path = entry
            .map_err(|e| format!("cannot list {}: {e}", dir.display()))?
            .path();
        let is_ply = path
            .extension()
            .is_some_and(|ext| ext.eq_ignore_ascii_case("ply"));
        if is_ply && path.is_file() {
            frames.push(path);
        }
    }
    if frames.is_empty() {
        return Err(format!("{} holds no .ply files", dir.display()));
    }
    // Zero-padded names (0000.ply, 0001.ply, ...) sort into frame order.
    frames.sort();
    Ok(frames)
}

/// The vertex count in the header of the `.ply` at `path` (read up to the header's end).
fn vertex_count(path: &Path) -> Result<usize, String> {
    let mut head = Vec::new();
    File::open(path)
        .and_then(|file| file.take(HEADER_BYTES).read_to_end(&mut head))
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let header = ply::parse_header(&head).map_err(|e| format!("{}: {e}", path.display()))?;
    header
        .element("vertex")
        .map(|vertex| vertex.count)
        .ok_or_else(|| format!("{}: the PLY header has no vertex element", path.display()))
}

impl Scene {
    /// Opens a `.ply4d`, a `.ply` or a folder of `.ply` frames. Every error is a message
    /// for the user; nothing here panics on bad input.
    pub fn open(path: &Path) -> Result<Self, String> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| path.display().to_string());
        if path.is_dir() {
            let frames = sequence_frames(path)?;
            let first = ply::read_ply(&frames[0]).map_err(describe)?;
            let timestamps = (0..frames.len()).map(|i| i as f64 / SEQUENCE_FPS).collect();
            let extent = SceneExtent::of_means(first.means.iter(), EXTENT_SAMPLES);
            return Ok(Self {
                sh_degree: first.sh_degree,
                static_set: GaussianSet {
                    sh_degree: first.sh_degree,
                    ..Default::default()
                },
                source: Source::Sequence(frames),
                name,
                timestamps,
                extent,
                antialiased: false,
            });
        }
        match sniff(path)? {
            Kind::Ply => {
                let set = ply::read_ply(path).map_err(describe)?;
                let extent = SceneExtent::of_means(set.means.iter(), EXTENT_SAMPLES);
                Ok(Self {
                    sh_degree: set.sh_degree,
                    static_set: set,
                    source: Source::Ply,
                    name,
                    timestamps: vec![0.0],
                    extent,
                    antialiased: false,
                })
            }
            Kind::Ply4d => {
                let reader = Ply4dReader::open(path).map_err(describe)?;
                let static_set = reader.read_static().map_err(describe)?;
                let mut timestamps = reader.header().meta.timestamps.clone();
                if timestamps.is_empty() {
                    // A scene with no dynamic sets still has one moment to show.
                    timestamps.push(0.0);
                }
                let extent = if static_set.is_empty() && reader.num_times() > 0 {
                    let first = reader.read_dynamic(0).map_err(describe)?;
                    SceneExtent::of_means(first.means.iter(), EXTENT_SAMPLES)
                } else {
                    SceneExtent::of_means(static_set.means.iter(), EXTENT_SAMPLES)
                };
                Ok(Self {
                    sh_degree: reader.header().sh_degree,
                    // Absent in files written before the key existed: classic.
                    antialiased: reader.header().meta.antialiased,
                    static_set,
                    source: Source::Ply4d(Box::new(reader)),
                    name,
                    timestamps,
                    extent,
                })
            }
        }
    }

    pub fn num_times(&self) -> usize {
        self.timestamps.len()
    }

    /// Whether the scene changes over time at all.
    pub fn is_dynamic(&self) -> bool {
        match &self.source {
            Source::Ply4d(reader) => reader.num_times() > 0,
            Source::Ply => false,
            Source::Sequence(_) => true,
        }
    }

    /// A version-2 scene's time model: its dynamic part is one spacetime set, a function of
    /// time (None for every other scene).
    pub fn time_model(&self) -> Option<TimeModel> {
        match &self.source {
            Source::Ply4d(reader) => reader.header().motion,
            Source::Ply | Source::Sequence(_) => None,
        }
    }

    /// How the shown time moves: continuously through a version-2 scene's function of time,
    /// else held at each timestamp until the next.
    pub fn timeline(&self) -> Timeline {
        match self.time_model() {
            Some(_) => Timeline::Continuous,
            None => Timeline::Held,
        }
    }

    /// A version-2 scene's spacetime set as stored, decoded from the memory-mapped file.
    pub fn spacetime_set(&self) -> Result<SpacetimeSet, String> {
        match &self.source {
            Source::Ply4d(reader) => reader.read_spacetime().map_err(describe),
            Source::Ply | Source::Sequence(_) => Err(format!("{} has no spacetime set", self.name)),
        }
    }

    /// The dynamic set of timestamp `t` (empty for a static scene), decoded from the
    /// memory-mapped file (a version-2 scene's evaluated at `t` on the CPU) or read from the
    /// frame's `.ply`.
    pub fn dynamic_set(&self, t: usize) -> Result<GaussianSet, String> {
        if t >= self.num_times() {
            return Err(format!(
                "timestamp index {t} out of range: the scene has {}",
                self.num_times()
            ));
        }
        match &self.source {
            Source::Ply4d(reader) if reader.num_times() > 0 => {
                reader.read_dynamic(t).map_err(describe)
            }
            Source::Ply4d(_) | Source::Ply => Ok(GaussianSet {
                sh_degree: self.static_set.sh_degree,
                ..Default::default()
            }),
            Source::Sequence(frames) => ply::read_ply(&frames[t]).map_err(describe),
        }
    }

    /// Gaussians in each timestamp's dynamic set, without decoding them: the `.ply4d`'s
    /// section table, or each frame file's header.
    pub fn dynamic_counts(&self) -> Result<Vec<usize>, String> {
        match &self.source {
            Source::Ply4d(reader) if reader.num_times() > 0 => Ok(reader
                .dynamic_counts()
                .into_iter()
                .map(|count| count as usize)
                .collect()),
            Source::Ply4d(_) | Source::Ply => Ok(vec![0; self.num_times()]),
            Source::Sequence(frames) => frames.iter().map(|f| vertex_count(f)).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic;

    fn temp_dir(tag: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("pano4d-view-scene-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn opens_ply4d_ply_and_sequence() {
        let dir = temp_dir("kinds");
        let scene = synthetic::scene(2_000, 200, 4, 0, 7);
        let p4 = dir.join("scene.ply4d");
        ply4d::write(&p4, &scene).unwrap();
        let opened = Scene::open(&p4).unwrap();
        assert_eq!(opened.num_times(), 4);
        assert_eq!(opened.static_set.len(), 2_000);
        assert_eq!(opened.dynamic_set(3).unwrap().len(), 200);
        assert!(opened.dynamic_set(4).is_err());
        assert_eq!(opened.timeline(), Timeline::Held);
        assert!(opened.spacetime_set().is_err());

        let p = dir.join("frame.ply");
        ply::write_ply(&p, &scene.static_set).unwrap();
        let single = Scene::open(&p).unwrap();
        assert_eq!(single.num_times(), 1);
        assert!(!single.is_dynamic());
        // A plain .ply records no mode: classic.
        assert!(!single.antialiased);
        assert!(single.dynamic_set(0).unwrap().is_empty());

        let seq = dir.join("seq");
        std::fs::create_dir_all(&seq).unwrap();
        for (t, set) in scene.dynamic.iter().enumerate() {
            ply::write_ply(seq.join(format!("{t:04}.ply")), set).unwrap();
        }
        std::fs::write(seq.join("notes.txt"), "not a frame").unwrap();
        let sequence = Scene::open(&seq).unwrap();
        assert_eq!(sequence.num_times(), 4);
        assert!(!sequence.antialiased);
        assert!(sequence.static_set.is_empty());
        assert_eq!(sequence.dynamic_set(1).unwrap(), scene.dynamic[1]);
        // Counts without decoding, from the section table or the frames' headers.
        let counts: Vec<usize> = scene.dynamic.iter().map(|set| set.len()).collect();
        assert_eq!(opened.dynamic_counts().unwrap(), counts);
        assert_eq!(sequence.dynamic_counts().unwrap(), counts);
        assert_eq!(single.dynamic_counts().unwrap(), vec![0]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn opens_a_version_2_ply4d_at_every_timestamp() {
        let dir = temp_dir("spacetime");
        let scene = synthetic::spacetime_scene(500, 100, 6, 1, 3);
        let path = dir.join("scene.ply4d");
        ply4d::write_spacetime(&path, &scene).unwrap();
        let opened = Scene::open(&path).unwrap();
        assert_eq!(opened.num_times(), 6);
        assert!(opened.is_dynamic());
        assert_eq!(opened.static_set, scene.static_set);
        assert_eq!(opened.timeline(), Timeline::Continuous);
        assert_eq!(opened.time_model(), Some(scene.dynamic.model));
        assert_eq!(opened.spacetime_set().unwrap(), scene.dynamic);
        for t in 0..6 {
            assert_eq!(opened.dynamic_set(t).unwrap(), scene.dynamic.at(t as f64));
        }
        assert!(opened.dynamic_set(6).is_err());
        assert_eq!(opened.dynamic_counts().unwrap(), vec![100; 6]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// `bytes` of a `.ply4d` as written before the `antialiased` key existed: the key is
    /// blanked with spaces (the JSON keeps its length, so the sections stay where the table
    /// says they are) and the header checksum over the JSON and the table is made again
    /// (the layout of docs/ply4d.md).
    fn without_antialiased_key(mut bytes: Vec<u8>) -> Vec<u8> {
        let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
        let json_end = ply4d::PREAMBLE_LEN + u32_at(12) as usize;
        let table_end = json_end + u32_at(16) as usize * ply4d::TABLE_ENTRY_LEN;
        let key = b"\"antialiased\":false,";
        let at = bytes[..json_end]
            .windows(key.len())
            .position(|window| window == key)
            .expect("the writer records the key");
        bytes[at..at + key.len()].fill(b' ');
        let crc = crc32fast::hash(&bytes[ply4d::PREAMBLE_LEN..table_end]);
        bytes[20..24].copy_from_slice(&crc.to_le_bytes());
        bytes
    }

    #[test]
    fn opens_a_ply4d_in_the_mode_its_header_records() {
        let dir = temp_dir("mode");
        let mut scene = synthetic::scene(300, 30, 2, 0, 3);
        let open_with = |scene: &ply4d::Scene4d, name: &str| {
            let path = dir.join(name);
            ply4d::write(&path, scene).unwrap();
            Scene::open(&path).unwrap()
        };
        scene.meta.antialiased = true;
        assert!(open_with(&scene, "antialiased.ply4d").antialiased);
        scene.meta.antialiased = false;
        assert!(!open_with(&scene, "classic.ply4d").antialiased);

        // A file from before the key: classic.
        let old = dir.join("old.ply4d");
        let bytes = std::fs::read(dir.join("classic.ply4d")).unwrap();
        std::fs::write(&old, without_antialiased_key(bytes)).unwrap();
        let opened = Scene::open(&old).unwrap();
        assert!(!opened.antialiased);
        assert_eq!(opened.dynamic_set(1).unwrap(), scene.dynamic[1]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn opens_the_real_guitar_in_both_layouts() {
        let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
        let standard = Scene::open(&data.join("gs_guitar.ply")).unwrap();
        let compressed = Scene::open(&data.join("gs_guitar.compressed.ply")).unwrap();
        for scene in [&standard, &compressed] {
            assert_eq!(scene.static_set.len(), 90_854);
            assert!(!scene.is_dynamic());
            assert_eq!(scene.num_times(), 1);
            // The guitar lies within 4.3 units of its capture frame's origin.
            let d = scene.extent.median_distance;
            assert!(d > 0.1 && d < 4.5, "{d}");
        }
    }

    #[test]
    fn bad_files_give_messages() {
        let dir = temp_dir("bad");
        let scene = synthetic::scene(500, 50, 2, 0, 1);
        let good = dir.join("good.ply4d");
        ply4d::write(&good, &scene).unwrap();
        let bytes = std::fs::read(&good).unwrap();

        let truncated = dir.join("truncated.ply4d");
        std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
        let err = Scene::open(&truncated).err().unwrap();
        assert!(
            err.contains("truncated") || err.contains("outside"),
            "{err}"
        );

        let corrupt = dir.join("corrupt.ply4d");
        let mut flipped = bytes.clone();
        let last = flipped.len() - 10;
        flipped[last] ^= 0xff;
        std::fs::write(&corrupt, &flipped).unwrap();
        // The header is fine; the damaged dynamic set fails when it is read.
        let opened = Scene::open(&corrupt).unwrap();
        assert!(opened.dynamic_set(1).unwrap_err().contains("checksum"));

        let jpeg = dir.join("photo.ply4d");
        std::fs::write(&jpeg, b"\xff\xd8\xff\xe0\x00\x10JFIF").unwrap();
        let err = Scene::open(&jpeg).err().unwrap();
        assert!(
            err.contains("neither a .ply4d scene nor a 3DGS .ply"),
            "{err}"
        );

        let empty = dir.join("empty.ply");
        std::fs::write(&empty, b"").unwrap();
        assert!(Scene::open(&empty).err().unwrap().contains("empty"));
        assert!(Scene::open(&dir.join("missing.ply4d"))
            .err()
            .unwrap()
            .contains("cannot open"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
