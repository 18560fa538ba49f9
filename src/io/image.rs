//! Photographs and textures: decoding (JPEG, PNG 8/16-bit, TIFF, EXR), header-only size
//! probing, and encoding textures for output.

use super::EncodedTexture;
use crate::error::{Error, Location, Result};
use image::{ColorType, DynamicImage, ImageDecoder, ImageReader, Rgb32FImage};
use std::path::Path;

fn open(path: &Path) -> Result<ImageReader<std::io::BufReader<std::fs::File>>> {
    ImageReader::open(path)
        .map_err(|e| Error::io(path, e))?
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))
}

fn decode_error(path: &Path, e: image::ImageError) -> Error {
    match e {
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::parse(
            path,
            Location::File,
            format!("cannot decode image: {other}"),
        ),
    }
}

/// Width and height from the file header, without decoding pixels.
pub fn dimensions(path: &Path) -> Result<(u32, u32)> {
    open(path)?
        .into_dimensions()
        .map_err(|e| decode_error(path, e))
}

/// The decoder's limits: photographs of 100+ MP exist, so the default 512 MiB allocation cap
/// is lifted to 4 GiB.
fn limits() -> image::Limits {
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(4 << 30);
    limits
}

/// Decodes an image file of any supported format.
pub fn read(path: &Path) -> Result<DynamicImage> {
    let mut r = open(path)?;
    r.limits(limits());
    r.decode().map_err(|e| decode_error(path, e))
}

/// Decodes an image to linear-in-file RGB floats in [0, 1] (no colour conversion: values are
/// the stored sRGB code values scaled, 16-bit PNG keeps its precision).
pub fn read_rgb32f(path: &Path) -> Result<Rgb32FImage> {
    read_rgb32f_into(path, Vec::new())
}

/// [`read_rgb32f`] into `spare`'s memory when the file is 8-bit RGB (most photographs): a
/// caller decoding photograph after photograph passes the last one's buffer back, which
/// saves the page faults of 180 MB of fresh memory per 12 MP photograph (the 8-bit pixels
/// are decoded into the buffer's last quarter and widened in place).
pub fn read_rgb32f_into(path: &Path, spare: Vec<f32>) -> Result<Rgb32FImage> {
    let mut r = open(path)?;
    r.limits(limits());
    let decoder = r.into_decoder().map_err(|e| decode_error(path, e))?;
    if decoder.color_type() != ColorType::Rgb8 {
        let img = DynamicImage::from_decoder(decoder).map_err(|e| decode_error(path, e))?;
        return Ok(img.into_rgb32f());
    }
    let (w, h) = decoder.dimensions();
    let n = usize::try_from(decoder.total_bytes())
        .map_err(|_| Error::parse(path, Location::File, "image too large for this machine"))?;
    let mut buf = spare;
    buf.clear();
    buf.resize(n, 0.0);
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut buf);
    decoder
        .read_image(&mut bytes[3 * n..])
        .map_err(|e| decode_error(path, e))?;
    // Value i moves from byte 3n + i to bytes 4i..4i + 4: a block's writes end at or before
    // its own reads' end (4 i1 <= 3n + i1 as i1 <= n), so copying each block's bytes out
    // first makes the widening safe in place.
    const BLOCK: usize = 4096;
    let mut tmp = [0u8; BLOCK];
    for i0 in (0..n).step_by(BLOCK) {
        let i1 = (i0 + BLOCK).min(n);
        let src = &mut tmp[..i1 - i0];
        src.copy_from_slice(&bytes[3 * n + i0..3 * n + i1]);
        for (out, &v) in bytes[4 * i0..4 * i1].chunks_exact_mut(4).zip(src.iter()) {
            // The image crate's own conversion: v / 255.
            out.copy_from_slice(&(f32::from(v) / 255.0).to_ne_bytes());
        }
    }
    Ok(Rgb32FImage::from_raw(w, h, buf).expect("3 values per pixel"))
}

/// Decodes encoded bytes (an embedded texture).
pub fn decode_bytes(bytes: &[u8], what: &Path) -> Result<DynamicImage> {
    image::load_from_memory(bytes).map_err(|e| decode_error(what, e))
}

/// Encodes an image as PNG (8- or 16-bit following the image's own depth).
pub fn encode_png(img: &DynamicImage) -> Result<EncodedTexture> {
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| Error::Invalid(format!("cannot encode PNG: {e}")))?;
    Ok(EncodedTexture {
        bytes,
        mime: "image/png",
    })
}

/// Encodes float RGB as OpenEXR (32-bit float channels), for the OBJ's texture file only:
/// glTF cannot carry EXR.
pub fn encode_exr(img: &Rgb32FImage) -> Result<EncodedTexture> {
    let mut bytes = Vec::new();
    DynamicImage::ImageRgb32F(img.clone())
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::OpenExr,
        )
        .map_err(|e| Error::Invalid(format!("cannot encode EXR: {e}")))?;
    Ok(EncodedTexture {
        bytes,
        mime: "image/x-exr",
    })
}

/// How an image for `scantex inpaint` was stored, so that it is written back the same way.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Depth {
    /// 8 bits per channel.
    U8,
    /// 16 bits per channel.
    U16,
    /// 32-bit float (EXR).
    F32,
}

/// Reads an image as grey or RGB floats (alpha dropped; 8- and 16-bit values scaled to [0, 1],
/// EXR as stored) and its depth.
pub fn read_planar(path: &Path) -> Result<(crate::restore::Image, Depth)> {
    use image::ColorType as C;
    let img = read(path)?;
    let depth = match img.color() {
        C::L8 | C::La8 | C::Rgb8 | C::Rgba8 => Depth::U8,
        C::L16 | C::La16 | C::Rgb16 | C::Rgba16 => Depth::U16,
        _ => Depth::F32,
    };
    let grey = matches!(img.color(), C::L8 | C::La8 | C::L16 | C::La16);
    let (w, h) = (img.width() as usize, img.height() as usize);
    let (channels, data) = if grey {
        (1, img.to_luma32f().into_raw())
    } else {
        (3, img.into_rgb32f().into_raw())
    };
    Ok((
        crate::restore::Image {
            width: w,
            height: h,
            channels,
            data,
        },
        depth,
    ))
}

/// Reads a mask: white (above one half of full scale, any channel's mean) = true.
pub fn read_mask(path: &Path) -> Result<(Vec<bool>, usize, usize)> {
    let img = read(path)?.to_luma32f();
    let (w, h) = (img.width() as usize, img.height() as usize);
    Ok((img.into_raw().into_iter().map(|v| v > 0.5).collect(), w, h))
}

/// Writes an image in the format its extension names (png, jpg/jpeg, exr), 16-bit PNG when
/// `depth` is 16-bit, atomically.
pub fn write_planar(path: &Path, img: &crate::restore::Image, depth: Depth) -> Result<()> {
    use image::{ImageBuffer, Luma, Rgb};
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let (w, h) = (img.width as u32, img.height as u32);
    let q8 = |v: &f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let q16 = |v: &f32| (v.clamp(0.0, 1.0) * 65535.0).round() as u16;
    let dynimg = match (ext.as_str(), img.channels, depth) {
        ("exr", 1, _) | ("exr", 3, _) => {
            // EXR carries RGB; grey becomes three equal channels.
            let rgb: Vec<f32> = if img.channels == 1 {
                img.data.iter().flat_map(|&v| [v, v, v]).collect()
            } else {
                img.data.clone()
            };
            DynamicImage::ImageRgb32F(
                ImageBuffer::<Rgb<f32>, _>::from_raw(w, h, rgb).expect("sized"),
            )
        }
        ("png", 1, Depth::U16 | Depth::F32) => DynamicImage::ImageLuma16(
            ImageBuffer::<Luma<u16>, _>::from_raw(w, h, img.data.iter().map(q16).collect())
                .expect("sized"),
        ),
        ("png", 3, Depth::U16 | Depth::F32) => DynamicImage::ImageRgb16(
            ImageBuffer::<Rgb<u16>, _>::from_raw(w, h, img.data.iter().map(q16).collect())
                .expect("sized"),
        ),
        ("png" | "jpg" | "jpeg", 1, _) => DynamicImage::ImageLuma8(
            ImageBuffer::<Luma<u8>, _>::from_raw(w, h, img.data.iter().map(q8).collect())
                .expect("sized"),
        ),
        ("png" | "jpg" | "jpeg", 3, _) => DynamicImage::ImageRgb8(
            ImageBuffer::<Rgb<u8>, _>::from_raw(w, h, img.data.iter().map(q8).collect())
                .expect("sized"),
        ),
        _ => {
            return Err(Error::parse(
                path,
                Location::File,
                "output format must be .png, .jpg, .jpeg or .exr",
            ))
        }
    };
    let format = match ext.as_str() {
        "exr" => image::ImageFormat::OpenExr,
        "png" => image::ImageFormat::Png,
        _ => image::ImageFormat::Jpeg,
    };
    let mut bytes = Vec::new();
    dynimg
        .write_to(&mut std::io::Cursor::new(&mut bytes), format)
        .map_err(|e| Error::parse(path, Location::File, format!("cannot encode: {e}")))?;
    super::write_atomic(path, &bytes)
}
