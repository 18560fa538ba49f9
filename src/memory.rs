//! The memory a texturing run will need, and the limit it must stay within: the page side is
//! chosen so that the estimate fits, and a run that cannot fit fails before any work.
//!
//! The estimate is a model fitted to measured peaks (`docs/decisions.md`, "Memory limit"):
//! a run holds the mesh with its atlas, the binding's views, two photographs in flight (one
//! decoded, one sampled, with its mip levels and depth map) and one atlas page's rasters,
//! layers and restoration crops. Stages before the pages (atlas, binding) need less than
//! the page stages on every scene measured, so the page stages' sum is the estimate.

use crate::error::{Error, Result};
use serde::Serialize;
use std::fmt;
use std::str::FromStr;

/// What does not grow with the scene: code, thread stacks, the allocator's heaps,
/// restoration's search structures (restoration peaks 90-120 MB above merging on the small
/// scenes, whatever the page side).
pub const BASE_BYTES: u64 = 128 << 20;
/// Per face of the welded mesh: positions, UVs, charts, and the per-face records each page's
/// sampling and merging build over the whole mesh (measured: 530 bytes at 1.17M faces, 570
/// per added face from 1.17M to 4.69M, 720 from 4.69M to 18.8M).
pub const FACE_BYTES: u64 = 720;
/// Per vertex-photograph view the binding keeps ([`crate::bind::ViewSample`], 20 bytes).
pub const VIEW_BYTES: u64 = 20;
/// Views per vertex assumed before binding has counted them (the speed scene: 9.6 with 50
/// photographs around the object; the sample and the corset: 3-5).
pub const ASSUMED_VIEWS: u64 = 16;
/// Per pixel of the largest photograph: two in flight, RGB8, mip levels and depth map
/// (12 MP photographs against 0.5 MP on the same page: 26 bytes per pixel), plus a masked
/// photograph's coverage levels (4 bytes per pixel of a third of a photograph, two in
/// flight: 3 more).
pub const PHOTO_PIXEL_BYTES: u64 = 29;
/// Per texel of a page: the texel raster, the merge's layers and accumulators, the colour,
/// source and weight planes, restoration's crops (16-41 measured across scenes and sides).
pub const TEXEL_BYTES: u64 = 40;

/// How much memory a run may use. Default: [`MemoryLimit::Share`] of 0.75, three quarters of
/// the machine's memory (or of the control group's limit, if lower).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum MemoryLimit {
    /// This share of the machine's memory, in (0, 1].
    Share(f64),
    /// This many bytes.
    Bytes(u64),
    /// No limit: the page side is what the photographs or the options ask.
    Off,
}

impl Default for MemoryLimit {
    fn default() -> Self {
        MemoryLimit::Share(0.75)
    }
}

impl fmt::Display for MemoryLimit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            MemoryLimit::Share(s) => write!(f, "{}%", s * 100.0),
            MemoryLimit::Bytes(b) => write!(f, "{}", human(b)),
            MemoryLimit::Off => f.write_str("off"),
        }
    }
}

impl FromStr for MemoryLimit {
    type Err = String;

    /// `75%`, `12G`, `512M`, `4096K`, a number of bytes, or `off`.
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let t = s.trim();
        if t.eq_ignore_ascii_case("off") {
            return Ok(MemoryLimit::Off);
        }
        let bad = || {
            format!(
                "'{s}' is not a memory limit: expected a share of the machine (75%), a size \
                 (12G, 512M, 4096K, bytes) or off"
            )
        };
        if let Some(p) = t.strip_suffix('%') {
            let v: f64 = p.trim().parse().map_err(|_| bad())?;
            if !(v > 0.0 && v <= 100.0) {
                return Err(format!(
                    "{s}: a share of the machine must lie in (0%, 100%]"
                ));
            }
            return Ok(MemoryLimit::Share(v / 100.0));
        }
        let upper = t.to_ascii_uppercase();
        let upper = upper.strip_suffix('B').unwrap_or(&upper);
        let upper = upper.strip_suffix('I').unwrap_or(upper);
        let (num, unit) = match upper.char_indices().last() {
            Some((i, 'K')) => (&upper[..i], 1u64 << 10),
            Some((i, 'M')) => (&upper[..i], 1 << 20),
            Some((i, 'G')) => (&upper[..i], 1 << 30),
            Some((i, 'T')) => (&upper[..i], 1 << 40),
            _ => (upper, 1),
        };
        let v: f64 = num.trim().parse().map_err(|_| bad())?;
        let bytes = v * unit as f64;
        if !(bytes >= 1.0 && bytes < u64::MAX as f64) {
            return Err(format!("{s}: a memory limit must be a positive size"));
        }
        Ok(MemoryLimit::Bytes(bytes as u64))
    }
}

impl MemoryLimit {
    /// The limit in bytes, with the machine's memory that a share refers to; `None` when off
    /// or when a share is asked and the machine's memory cannot be read.
    pub fn bytes(&self) -> Option<u64> {
        match *self {
            MemoryLimit::Share(s) => machine_memory().map(|m| (m as f64 * s) as u64),
            MemoryLimit::Bytes(b) => Some(b),
            MemoryLimit::Off => None,
        }
    }

    /// Checks that a share lies in (0, 1] and a size is positive.
    pub fn validate(&self) -> Result<()> {
        match *self {
            MemoryLimit::Share(s) if !(s > 0.0 && s <= 1.0) => Err(Error::option(
                "memory_limit",
                format!("a share of {s}: expected (0, 1]"),
            )),
            MemoryLimit::Bytes(0) => Err(Error::option(
                "memory_limit",
                "0 bytes: expected a positive size",
            )),
            _ => Ok(()),
        }
    }
}

/// The machine's memory as this process may use it: the smaller of the physical memory
/// (`MemTotal`) and the control group's limit (`memory.max`), bytes; `None` where neither
/// can be read (not Linux).
pub fn machine_memory() -> Option<u64> {
    let total = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| {
        let line = s.lines().find(|l| l.starts_with("MemTotal:"))?;
        line.split_whitespace()
            .nth(1)?
            .parse::<u64>()
            .ok()
            .map(|kb| kb * 1024)
    });
    let group = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok());
    match (total, group) {
        (Some(t), Some(g)) => Some(t.min(g)),
        (t, g) => t.or(g),
    }
}

/// What a run is estimated to need, bytes, by part.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Estimate {
    /// The process itself ([`BASE_BYTES`]).
    pub base: u64,
    /// The mesh with its atlas and per-face records ([`FACE_BYTES`] per face).
    pub mesh: u64,
    /// The binding's views ([`VIEW_BYTES`] each; counted once binding is done, assumed
    /// [`ASSUMED_VIEWS`] per vertex, or the binding cap if lower, before).
    pub binding: u64,
    /// Two photographs in flight ([`PHOTO_PIXEL_BYTES`] per pixel of the largest).
    pub photos: u64,
    /// One atlas page ([`TEXEL_BYTES`] per texel).
    pub page: u64,
}

impl Estimate {
    /// The estimate for `faces` faces, `views` binding views, photographs of at most
    /// `photo_pixels` pixels and pages of `side` x `side` texels.
    pub fn new(faces: u64, views: u64, photo_pixels: u64, side: u32) -> Estimate {
        Estimate {
            base: BASE_BYTES,
            mesh: faces.saturating_mul(FACE_BYTES),
            binding: views.saturating_mul(VIEW_BYTES),
            photos: photo_pixels.saturating_mul(PHOTO_PIXEL_BYTES),
            page: u64::from(side).pow(2).saturating_mul(TEXEL_BYTES),
        }
    }

    /// The whole estimate, bytes.
    pub fn total(&self) -> u64 {
        self.base
            .saturating_add(self.mesh)
            .saturating_add(self.binding)
            .saturating_add(self.photos)
            .saturating_add(self.page)
    }

    /// The estimate with pages of `side` instead.
    pub fn with_side(&self, side: u32) -> Estimate {
        Estimate {
            page: u64::from(side).pow(2).saturating_mul(TEXEL_BYTES),
            ..*self
        }
    }

    /// "3.2 GiB (mesh 402 MiB, binding 109 MiB, photographs 298 MiB, a 8192 page 2.5 GiB)".
    pub fn describe(&self, side: u32) -> String {
        format!(
            "{} (mesh {}, binding {}, photographs {}, a {side} page {})",
            human(self.total()),
            human(self.mesh),
            human(self.binding),
            human(self.photos),
            human(self.page)
        )
    }
}

/// The largest page side at most `side` whose estimate fits `limit`, halving `side` (never
/// under `min_side`); `None` if not even `min_side` fits.
pub fn fitting_side(est: &Estimate, side: u32, min_side: u32, limit: u64) -> Option<u32> {
    let mut s = side;
    loop {
        if est.with_side(s).total() <= limit {
            return Some(s);
        }
        if s / 2 < min_side {
            return None;
        }
        s /= 2;
    }
}

/// The error of a run that cannot fit `limit`: the estimate, the limit and what to change.
pub fn over_limit(est: &Estimate, side: u32, limit: &MemoryLimit, advice: &str) -> Error {
    let est = est.with_side(side);
    let of = match *limit {
        MemoryLimit::Share(s) => match machine_memory() {
            Some(m) => format!(" ({}% of this machine's {})", s * 100.0, human(m)),
            None => String::new(),
        },
        _ => String::new(),
    };
    Error::option(
        "memory_limit",
        format!(
            "the run would need about {}, over the memory limit of {}{of}: {advice}",
            est.describe(side),
            human(limit.bytes().unwrap_or(0)),
        ),
    )
}

/// Bytes as "1.4 GiB", "350 MiB": binary units, as `--memory-limit 12G` reads.
pub fn human(b: u64) -> String {
    if b >= 1 << 30 {
        format!("{:.1} GiB", b as f64 / f64::from(1u32 << 30))
    } else {
        format!("{:.0} MiB", b as f64 / f64::from(1u32 << 20))
    }
}

/// Buffers of `f32` that one photograph's work freed, for the next photograph's buffers of
/// the same length (depth maps, mip levels). A loop over photographs that allocates them
/// afresh maps new memory each time, and every page of it faults in again on its first write
/// (`docs/decisions.md`, "Page faults in the photo loops"). Holds the newest `cap` buffers
/// at most, so that photographs of several sizes cannot pile up buffers nothing fits.
#[derive(Debug, Default)]
pub struct SpareBuffers {
    bufs: Vec<Vec<f32>>,
    cap: usize,
}

impl SpareBuffers {
    /// Keeps at most `cap` buffers (0: none).
    pub fn new(cap: usize) -> Self {
        SpareBuffers {
            bufs: Vec::new(),
            cap,
        }
    }

    /// A spare buffer of exactly `len` values, its old values still in it, if there is one.
    pub fn take(&mut self, len: usize) -> Option<Vec<f32>> {
        let k = self.bufs.iter().position(|b| b.len() == len)?;
        Some(self.bufs.swap_remove(k))
    }

    /// Keeps `bufs`, dropping the oldest beyond the cap.
    pub fn put(&mut self, bufs: impl IntoIterator<Item = Vec<f32>>) {
        self.bufs.extend(bufs);
        let excess = self.bufs.len().saturating_sub(self.cap);
        self.bufs.drain(..excess);
    }

    /// Buffers held.
    pub fn len(&self) -> usize {
        self.bufs.len()
    }

    /// Whether no buffer is held.
    pub fn is_empty(&self) -> bool {
        self.bufs.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A buffer comes back only at its exact length, and beyond the cap the oldest go.
    #[test]
    fn spare_buffers_match_lengths_and_keep_the_newest() {
        let mut s = SpareBuffers::new(2);
        s.put([vec![1.0; 3], vec![2.0; 4]]);
        assert_eq!(s.take(5), None);
        s.put([vec![3.0; 3]]);
        assert_eq!(s.len(), 2);
        // The oldest (1.0, length 3) went; the newest of length 3 is 3.0.
        assert_eq!(s.take(3), Some(vec![3.0; 3]));
        assert_eq!(s.take(3), None);
        assert_eq!(s.take(4), Some(vec![2.0; 4]));
        assert!(s.is_empty());
        let mut none = SpareBuffers::new(0);
        none.put([vec![0.0; 3]]);
        assert!(none.is_empty());
    }

    #[test]
    fn limits_parse_as_shares_sizes_and_off() {
        assert_eq!("75%".parse(), Ok(MemoryLimit::Share(0.75)));
        assert_eq!("12G".parse(), Ok(MemoryLimit::Bytes(12 << 30)));
        assert_eq!("12GiB".parse(), Ok(MemoryLimit::Bytes(12 << 30)));
        assert_eq!("1.5g".parse(), Ok(MemoryLimit::Bytes(3 << 29)));
        assert_eq!("512M".parse(), Ok(MemoryLimit::Bytes(512 << 20)));
        assert_eq!("1000".parse(), Ok(MemoryLimit::Bytes(1000)));
        assert_eq!("off".parse(), Ok(MemoryLimit::Off));
        for bad in ["", "-1G", "0", "0%", "150%", "G", "12Q", "nan%", "1e30T"] {
            assert!(bad.parse::<MemoryLimit>().is_err(), "{bad}");
        }
        // Display reads back.
        for l in [MemoryLimit::Share(0.75), MemoryLimit::Off] {
            assert_eq!(l.to_string().parse(), Ok(l));
        }
    }

    #[test]
    fn the_fitting_side_halves_until_the_estimate_fits() {
        let est = Estimate::new(1_000_000, 10_000_000, 12_000_000, 8192);
        let fixed = est.with_side(0).total();
        // Room for exactly a 2048 page beside the rest.
        let limit = fixed + 2048 * 2048 * TEXEL_BYTES;
        assert_eq!(fitting_side(&est, 8192, 16, limit), Some(2048));
        assert_eq!(fitting_side(&est, 8192, 16, limit - 1), Some(1024));
        assert_eq!(fitting_side(&est, 8192, 4096, limit), None);
        assert_eq!(fitting_side(&est, 8192, 16, u64::MAX), Some(8192));
        assert_eq!(fitting_side(&est, 8192, 16, fixed), None);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn the_machine_has_memory_and_a_share_of_it_is_less() {
        let m = machine_memory().expect("Linux reports its memory");
        assert!(m > 100 << 20, "{m} bytes");
        let l = MemoryLimit::Share(0.5).bytes().unwrap();
        assert!(l <= m / 2 + 1 && l + 1 >= m / 2, "{l} of {m}");
    }
}
