//! Reading and writing files: meshes (OBJ, PLY, glTF/GLB), images, and atomic output.
//! This is the only module that opens files (besides the COLMAP format in `camera::colmap`,
//! which uses [`write_atomic`]). Every output goes through [`staging`].

pub mod gltf;
pub mod image;
pub mod obj;
pub mod ply;
pub mod staging;

pub use staging::{write_atomic, Staged};

use crate::error::{Error, Result};
use crate::mesh::{LoadReport, Mesh};
use std::path::Path;

/// Mesh file formats scantex reads and writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ (+ MTL + texture image).
    Obj,
    /// Stanford PLY.
    Ply,
    /// glTF 2.0, JSON (`.gltf` with external buffers).
    Gltf,
    /// glTF 2.0, binary container (`.glb`).
    Glb,
}

impl MeshFormat {
    /// The format for a file name's extension (case-insensitive).
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "obj" => Some(MeshFormat::Obj),
            "ply" => Some(MeshFormat::Ply),
            "gltf" => Some(MeshFormat::Gltf),
            "glb" => Some(MeshFormat::Glb),
            _ => None,
        }
    }
}

/// Reads a mesh (OBJ, PLY, glTF or GLB, by extension), validates it and drops degenerate
/// and repeated faces. The report says what was dropped or triangulated.
pub fn read_mesh(path: &Path) -> Result<(Mesh, LoadReport)> {
    let format = MeshFormat::from_path(path).ok_or_else(|| {
        Error::at_element(
            path,
            "file name",
            "unknown mesh format: expected .obj, .ply, .gltf or .glb",
        )
    })?;
    if !path.is_file() {
        return Err(Error::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "mesh file not found"),
        ));
    }
    let (mut mesh, mut report) = match format {
        MeshFormat::Obj => obj::read(path)?,
        MeshFormat::Ply => ply::read(path)?,
        MeshFormat::Gltf | MeshFormat::Glb => gltf::read(path)?,
    };
    let v = mesh.validate(path)?;
    report.degenerate_faces += v.degenerate_faces;
    report.duplicate_faces += v.duplicate_faces;
    Ok((mesh, report))
}

/// Peak resident memory of this process so far, bytes (Linux `VmHWM`; `None` elsewhere).
pub fn peak_memory() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Resident memory of this process now, bytes (Linux `statm`; `None` elsewhere).
pub fn resident_memory() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = s.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * page_size())
}

fn page_size() -> u64 {
    #[cfg(unix)]
    // SAFETY: sysconf reads a constant of the system.
    let n = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    #[cfg(not(unix))]
    let n = 4096;
    u64::try_from(n).unwrap_or(4096)
}

/// Makes the memory under `s` resident by writing to it first. Zeroed memory fresh from the
/// system (large `vec![0; n]`) is mapped on first touch; if that touch is a read, as in `+=`,
/// the kernel maps its shared zero page and the write right after faults a second time and
/// flushes every core's TLB (an interrupt to the other core per 4 KB page). A locked
/// read-modify-write is a write access, so a page not yet touched is mapped once, writable.
/// Values are unchanged; pages already resident cost one atomic operation each.
pub fn touch_for_writing<T>(s: &mut [T]) {
    use std::sync::atomic::{AtomicU8, Ordering};
    // The smallest page size of the platforms scantex builds for: larger pages are touched
    // more than once, which is harmless.
    const PAGE: usize = 4096;
    let bytes = std::mem::size_of_val(s);
    if bytes == 0 {
        return;
    }
    let p = s.as_mut_ptr().cast::<u8>();
    let first_boundary = (PAGE - p as usize % PAGE) % PAGE;
    let offsets = std::iter::once(0).chain((first_boundary..bytes).step_by(PAGE));
    for off in offsets {
        // SAFETY: `off < bytes`, so the byte lies inside `s`, which the `&mut` borrow gives
        // this function alone; an atomic OR with 0 leaves it as it was. The 0 is opaque to the
        // compiler, which would otherwise turn an OR with a known 0 into a plain load.
        unsafe { AtomicU8::from_ptr(p.add(off)) }
            .fetch_or(std::hint::black_box(0), Ordering::Relaxed);
    }
}

/// How often [`MemoryWatch`] looks.
const WATCH_PERIOD: std::time::Duration = std::time::Duration::from_millis(5);

/// The peak resident memory of each part of a run: a thread reads the resident size every 5
/// ms. The kernel's high-water mark ([`peak_memory`]) only rises, and resetting it would
/// also reset what `time` and a calling process see as the run's peak.
pub struct MemoryWatch {
    peak: std::sync::Arc<std::sync::atomic::AtomicU64>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl MemoryWatch {
    /// Starts watching (where the resident size cannot be read, [`MemoryWatch::take`] gives 0).
    pub fn start() -> MemoryWatch {
        use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
        use std::sync::Arc;
        let peak = Arc::new(AtomicU64::new(resident_memory().unwrap_or(0)));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = resident_memory().is_some().then(|| {
            let (peak, stop) = (peak.clone(), stop.clone());
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    if let Some(r) = resident_memory() {
                        peak.fetch_max(r, Ordering::Relaxed);
                    }
                    std::thread::sleep(WATCH_PERIOD);
                }
            })
        });
        MemoryWatch { peak, stop, thread }
    }

    /// The peak resident bytes since the last call (or the start); the next call's peak
    /// starts from the size now.
    pub fn take(&self) -> u64 {
        let now = resident_memory().unwrap_or(0);
        self.peak
            .swap(now, std::sync::atomic::Ordering::Relaxed)
            .max(now)
    }
}

impl Drop for MemoryWatch {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Returns memory the allocator holds but no longer uses to the system (glibc's
/// `malloc_trim`; a no-op elsewhere). glibc keeps freed small and mid-sized blocks in its
/// heaps, so memory freed by one stage (the merge's thousand chart accumulators) would
/// otherwise stay resident while the next one (the atlas they collapse into) grows.
pub fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free pages of the allocator's own heaps.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// While alive, the allocator serves blocks up to 256 MB from its heaps (threads' own heaps
/// still map blocks over their 64 MB size) and keeps up to 128 MB free at a heap's top,
/// instead of mapping and unmapping each large block (glibc's `mallopt`, which accepts these
/// values on glibc 2.36; a no-op elsewhere). A loop that allocates and frees the same large buffers
/// over and over (the merge's per-photograph layers, depth maps and mip levels) then reuses
/// them: every unmap of a block costs the other core an interrupt to flush its TLB, and every
/// new map a page fault per 4 KB. Dropping the guard sets glibc's defaults back as its own
/// adjustment leaves them after large frees (32 MB and 64 MB) and returns the free memory.
pub struct LargeBlocksInHeap(());

impl LargeBlocksInHeap {
    /// Starts serving large blocks from the heaps.
    pub fn new() -> Self {
        set_thresholds(256 << 20, 128 << 20);
        LargeBlocksInHeap(())
    }
}

impl Default for LargeBlocksInHeap {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for LargeBlocksInHeap {
    fn drop(&mut self) {
        set_thresholds(32 << 20, 64 << 20);
        release_freed_memory();
    }
}

#[allow(unused_variables)]
fn set_thresholds(mmap: i32, trim: i32) {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes the allocator's thresholds for later calls.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, mmap);
        libc::mallopt(libc::M_TRIM_THRESHOLD, trim);
    }
}

/// An encoded texture image ready to be written beside or inside a mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct EncodedTexture {
    /// The encoded bytes (PNG or JPEG, the only images glTF allows; EXR for OBJ only).
    pub bytes: Vec<u8>,
    /// MIME type, `image/png`, `image/jpeg` or `image/x-exr`.
    pub mime: &'static str,
}

impl EncodedTexture {
    /// File extension matching the MIME type.
    pub fn extension(&self) -> &'static str {
        match self.mime {
            "image/jpeg" => "jpg",
            "image/x-exr" => "exr",
            _ => "png",
        }
    }
}

/// Writes `mesh` in the format its extension names (OBJ writes `.mtl` and the texture beside
/// it). All files appear together or not at all.
pub fn write_mesh(path: &Path, mesh: &Mesh, texture: Option<&EncodedTexture>) -> Result<()> {
    let mut staged = Staged::new(&staging::label_of(path));
    stage_mesh(&mut staged, path, mesh, texture)?;
    staged.commit()
}

/// [`write_mesh`] into staging the caller commits with its other outputs.
pub fn stage_mesh(
    staged: &mut Staged,
    path: &Path,
    mesh: &Mesh,
    texture: Option<&EncodedTexture>,
) -> Result<()> {
    match MeshFormat::from_path(path) {
        Some(MeshFormat::Obj) => obj::write(staged, path, mesh, texture),
        Some(MeshFormat::Ply) => ply::write(staged, path, mesh),
        Some(MeshFormat::Glb) => gltf::write_glb(staged, path, mesh, texture),
        Some(MeshFormat::Gltf) | None => Err(Error::at_element(
            path,
            "file name",
            "mesh output must be .obj, .ply or .glb",
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn touching_for_writing_leaves_every_value_as_it_was() {
        // Slices that start and end inside pages, span many, hold one element or none.
        let mut v: Vec<u16> = (0..20_000u16).collect();
        for (a, b) in [(0, 0), (1, 2), (3, 9_999), (4_095, 12_001), (0, 20_000)] {
            touch_for_writing(&mut v[a..b]);
        }
        assert!(v.iter().enumerate().all(|(i, &x)| usize::from(x) == i));
        let mut z = vec![[0f32; 3]; 1 << 20];
        z[123_456] = [1.0, -2.0, f32::NAN];
        touch_for_writing(&mut z[7..]);
        assert_eq!(z[123_456][..2], [1.0, -2.0]);
        assert!(z[123_456][2].is_nan());
        assert_eq!(z.iter().filter(|t| **t == [0.0; 3]).count(), (1 << 20) - 1);
    }
}
