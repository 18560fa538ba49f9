//! The photo loop of stages 2-4: every photograph decoded in order, the next one (and its
//! per-photograph preparation) while the current one is used, so at most two are in memory
//! whatever the number of photographs.

use crate::error::Result;
use crate::io::image::PhotoPixels;
use crate::progress::Progress;
use crate::scene::Photo;
use image::GrayImage;

/// A decoded photograph with its mask.
struct Decoded {
    rgb: PhotoPixels,
    mask: Option<GrayImage>,
}

fn decode(p: &Photo, spare: Vec<u8>) -> Result<Decoded> {
    Ok(Decoded {
        rgb: p.load_pixels(spare)?,
        mask: p.load_mask()?,
    })
}

/// Runs `work` on every photograph in order, decoding the next one while `work` runs on the
/// current one: at most two photographs are in memory.
pub(crate) fn for_each_photo(
    photos: &[Photo],
    progress: &dyn Progress,
    mut work: impl FnMut(usize, &PhotoPixels, Option<&GrayImage>) -> Result<()> + Send,
) -> Result<()> {
    for_each_photo_with(
        photos,
        progress,
        |_, _| (),
        |i, rgb, mask, ()| work(i, rgb, mask),
    )
}

/// [`for_each_photo`] with a per-photograph `prepare` step (depth map, mip pyramid) that runs
/// with the decoding, beside `work` on the previous photograph, and whose result `work` gets.
pub(crate) fn for_each_photo_with<T: Send>(
    photos: &[Photo],
    progress: &dyn Progress,
    prepare: impl Fn(usize, &PhotoPixels) -> T + Sync,
    mut work: impl FnMut(usize, &PhotoPixels, Option<&GrayImage>, T) -> Result<()> + Send,
) -> Result<()> {
    if photos.is_empty() {
        return Ok(());
    }
    let load = |i: usize, spare: Vec<u8>| -> Result<(Decoded, T)> {
        let d = decode(&photos[i], spare)?;
        let t = prepare(i, &d.rgb);
        Ok((d, t))
    };
    let mut current = load(0, Vec::new())?;
    // The buffer of the photograph before the current one, for the next one to decode into.
    let mut spare = Vec::new();
    for i in 0..photos.len() {
        let (cur, extra) = current;
        let (next, done) = rayon::join(
            || {
                (i + 1 < photos.len())
                    .then(|| load(i + 1, std::mem::take(&mut spare)))
                    .transpose()
            },
            || work(i, &cur.rgb, cur.mask.as_ref(), extra),
        );
        done?;
        spare = cur.rgb.into_spare();
        progress.advance(1);
        match next? {
            Some(n) => current = n,
            None => break,
        }
    }
    Ok(())
}
