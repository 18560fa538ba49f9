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
    let (rgb, mask) = p.load_with_mask(spare)?;
    Ok(Decoded { rgb, mask })
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
        None,
        progress,
        |_, _, _| (),
        |i, rgb, mask, ()| work(i, rgb, mask),
    )
}

/// [`for_each_photo`] with a per-photograph `prepare` step (depth map, mip pyramid; it gets
/// the photograph and its mask) that runs
/// with the decoding, beside `work` on the previous photograph, and whose result `work` gets.
/// With `wanted`, only the photographs it marks are decoded and worked on (in order): a
/// page's charts are seen by some of the photographs, and decoding is most of a photograph's
/// cost.
pub(crate) fn for_each_photo_with<T: Send>(
    photos: &[Photo],
    wanted: Option<&[bool]>,
    progress: &dyn Progress,
    prepare: impl Fn(usize, &PhotoPixels, Option<&GrayImage>) -> T + Sync,
    mut work: impl FnMut(usize, &PhotoPixels, Option<&GrayImage>, T) -> Result<()> + Send,
) -> Result<()> {
    let order: Vec<usize> = (0..photos.len())
        .filter(|&i| wanted.is_none_or(|w| w.get(i).copied().unwrap_or(false)))
        .collect();
    // The ones left out count as done at once, so progress still ends at the total.
    progress.advance((photos.len() - order.len()) as u64);
    let Some(&first) = order.first() else {
        return Ok(());
    };
    let load = |i: usize, spare: Vec<u8>| -> Result<(Decoded, T)> {
        let d = decode(&photos[i], spare)?;
        let t = prepare(i, &d.rgb, d.mask.as_ref());
        Ok((d, t))
    };
    let mut current = load(first, Vec::new())?;
    // The buffer of the photograph before the current one, for the next one to decode into.
    let mut spare = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        let (cur, extra) = current;
        let (next, done) = rayon::join(
            || {
                order
                    .get(k + 1)
                    .map(|&j| load(j, std::mem::take(&mut spare)))
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
