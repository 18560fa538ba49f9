//! Photographs and textures: decoding (JPEG, PNG 8/16-bit, TIFF, EXR), header-only size
//! probing, and encoding textures for output.

use super::EncodedTexture;
use crate::error::{Error, Location, Result};
use image::{DynamicImage, ImageReader, Rgb32FImage};
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

/// Decodes an image file of any supported format.
pub fn read(path: &Path) -> Result<DynamicImage> {
    let mut r = open(path)?;
    // Photographs of 100+ MP exist; lift the decoder's default 512 MiB cap to 4 GiB.
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(4 << 30);
    r.limits(limits);
    r.decode().map_err(|e| decode_error(path, e))
}

/// Decodes an image to linear-in-file RGB floats in [0, 1] (no colour conversion: values are
/// the stored sRGB code values scaled, 16-bit PNG keeps its precision).
pub fn read_rgb32f(path: &Path) -> Result<Rgb32FImage> {
    Ok(read(path)?.into_rgb32f())
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
