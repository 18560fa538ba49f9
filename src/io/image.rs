//! Photographs and textures: decoding (JPEG, PNG 8/16-bit, TIFF, EXR), header-only size
//! probing, and encoding textures for output.

use super::EncodedTexture;
use crate::error::{Error, Location, Result};
use image::{ColorType, DynamicImage, GrayImage, ImageDecoder, ImageReader, Rgb32FImage};
use std::path::Path;

fn open(path: &Path) -> Result<ImageReader<std::io::BufReader<std::fs::File>>> {
    ImageReader::open(path)
        .map_err(|e| Error::io(path, e))?
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))
}

fn decode_error(path: &Path, e: image::ImageError) -> Error {
    match e {
        image::ImageError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::parse(
                path,
                Location::File,
                "truncated image: the file ends before its pixel data does",
            )
        }
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::parse(
            path,
            Location::File,
            format!("cannot decode image: {other}"),
        ),
    }
}

/// Checks that an image file is whole: decoders fill the missing rows of a truncated JPEG with
/// grey and report success, so a JPEG must carry its end-of-image marker after its first scan.
/// Cheap: the tail of the file is read, and the whole file only when something follows the
/// marker (an appended video, say). Other formats' decoders report truncation themselves.
pub fn check_complete(path: &Path) -> Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut head = [0u8; 2];
    if f.read_exact(&mut head).is_err() || head != [0xFF, 0xD8] {
        return Ok(());
    }
    let len = f.metadata().map_err(|e| Error::io(path, e))?.len();
    let tail_len = len.min(4096);
    f.seek(SeekFrom::Start(len - tail_len))
        .map_err(|e| Error::io(path, e))?;
    let mut tail = Vec::with_capacity(tail_len as usize);
    f.read_to_end(&mut tail).map_err(|e| Error::io(path, e))?;
    // Some writers pad after the marker.
    let end = tail
        .iter()
        .rposition(|&b| !matches!(b, 0 | b'\n' | b'\r' | b' '))
        .map_or(0, |i| i + 1);
    if tail[..end].ends_with(&[0xFF, 0xD9]) {
        return Ok(());
    }
    let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    check_complete_bytes(path, &data)
}

/// [`check_complete`] on a file's bytes; `path` is only used in errors.
pub fn check_complete_bytes(path: &Path, data: &[u8]) -> Result<()> {
    if !data.starts_with(&[0xFF, 0xD8]) {
        return Ok(());
    }
    match jpeg_eoi_after_scan(data) {
        Ok(()) => Ok(()),
        Err(at) => Err(Error::parse(
            path,
            Location::Byte(at as u64),
            format!(
                "truncated or corrupt JPEG: no end-of-image marker after the image data \
                 ({} bytes)",
                data.len()
            ),
        )),
    }
}

/// Decodes an image file's bytes as [`read`] does (completeness checked first), with at most
/// `max_alloc` bytes allocated by the decoder; `path` is only used in errors.
pub fn decode_checked(path: &Path, data: &[u8], max_alloc: u64) -> Result<DynamicImage> {
    check_complete_bytes(path, data)?;
    let mut r = ImageReader::new(std::io::Cursor::new(data))
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(max_alloc);
    r.limits(limits);
    r.decode().map_err(|e| decode_error(path, e))
}

/// A mask from an image: white (above one half of full scale, any channel's mean) = true.
pub fn mask_of(img: &DynamicImage) -> (Vec<bool>, usize, usize) {
    let img = img.to_luma32f();
    let (w, h) = (img.width() as usize, img.height() as usize);
    (img.into_raw().into_iter().map(|v| v > 0.5).collect(), w, h)
}

/// `Ok` if the JPEG in `data` has an end-of-image marker after its first scan; else the byte
/// offset where the marker was expected. Marker segments before the scan are skipped by their
/// lengths, so a thumbnail's own marker inside the EXIF block does not count.
fn jpeg_eoi_after_scan(data: &[u8]) -> std::result::Result<(), usize> {
    let mut i = 2;
    loop {
        // Fill bytes (0xFF) may precede a marker.
        while i < data.len() && data[i] == 0xFF && data.get(i + 1) == Some(&0xFF) {
            i += 1;
        }
        if i + 4 > data.len() || data[i] != 0xFF {
            return Err(i.min(data.len()));
        }
        let marker = data[i + 1];
        if marker == 0xD9 {
            return Ok(());
        }
        if (0xD0..=0xD7).contains(&marker) || marker == 0x01 {
            i += 2;
            continue;
        }
        let seg = u16::from_be_bytes([data[i + 2], data[i + 3]]) as usize;
        if seg < 2 {
            return Err(i);
        }
        i += 2 + seg;
        if marker == 0xDA {
            // Entropy-coded data: 0xFF is always followed by 0x00 or a restart marker there, so
            // the first 0xFF 0xD9 is the end of the image.
            return match data[i.min(data.len())..]
                .windows(2)
                .position(|w| w == [0xFF, 0xD9])
            {
                Some(_) => Ok(()),
                None => Err(data.len()),
            };
        }
    }
}

/// Whether the file's pixels carry an alpha channel, from its header (no pixel decoding).
pub fn has_alpha(path: &Path) -> Result<bool> {
    let decoder = open(path)?
        .into_decoder()
        .map_err(|e| decode_error(path, e))?;
    Ok(image::ImageDecoder::color_type(&decoder).has_alpha())
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
    check_complete(path)?;
    let mut r = open(path)?;
    r.limits(limits());
    r.decode().map_err(|e| decode_error(path, e))
}

/// Decodes an image to linear-in-file RGB floats in [0, 1] (no colour conversion: values are
/// the stored sRGB code values scaled, 16-bit PNG keeps its precision).
pub fn read_rgb32f(path: &Path) -> Result<Rgb32FImage> {
    Ok(read(path)?.into_rgb32f())
}

/// A decoded photograph: 8-bit RGB as stored (most photographs; a quarter of the memory of
/// floats), or floats for 16-bit and float files. Either way values read as floats in
/// [0, 1], 8-bit ones as `v / 255` exactly as the image crate converts them, so both give the
/// same numbers as [`read_rgb32f`].
#[derive(Debug, Clone, PartialEq)]
pub enum PhotoPixels {
    /// 8-bit RGB.
    Rgb8(image::RgbImage),
    /// RGB floats.
    Rgb32F(Rgb32FImage),
}

/// `v / 255` for every 8-bit value: the image crate's conversion, as a table.
pub(crate) const U8_TO_F32: [f32; 256] = {
    let mut t = [0f32; 256];
    let mut i = 0;
    while i < 256 {
        t[i] = i as f32 / 255.0;
        i += 1;
    }
    t
};

/// Flat RGB values readable as floats: the raw buffers of both kinds of [`PhotoPixels`], so
/// that per-pixel loops can be written once and compiled for each.
pub(crate) trait Values: Sync {
    /// Value `i` of the flat buffer, in [0, 1].
    fn value(&self, i: usize) -> f32;
}

impl Values for [u8] {
    #[inline(always)]
    fn value(&self, i: usize) -> f32 {
        U8_TO_F32[self[i] as usize]
    }
}

impl Values for [f32] {
    #[inline(always)]
    fn value(&self, i: usize) -> f32 {
        self[i]
    }
}

impl PhotoPixels {
    /// Width and height in pixels.
    pub fn dimensions(&self) -> (u32, u32) {
        match self {
            PhotoPixels::Rgb8(i) => i.dimensions(),
            PhotoPixels::Rgb32F(i) => i.dimensions(),
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.dimensions().0
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.dimensions().1
    }

    /// Pixel (`x`, `y`) as floats in [0, 1].
    #[inline]
    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        let i = 3 * (y as usize * self.width() as usize + x as usize);
        match self {
            PhotoPixels::Rgb8(img) => {
                let r = img.as_raw();
                [r.value(i), r.value(i + 1), r.value(i + 2)]
            }
            PhotoPixels::Rgb32F(img) => {
                let r = img.as_raw();
                [r[i], r[i + 1], r[i + 2]]
            }
        }
    }

    /// The pixels as floats.
    pub fn into_rgb32f(self) -> Rgb32FImage {
        match self {
            PhotoPixels::Rgb8(img) => DynamicImage::ImageRgb8(img).into_rgb32f(),
            PhotoPixels::Rgb32F(img) => img,
        }
    }

    /// The 8-bit buffer, for the next photograph to decode into ([`read_photo_and_alpha`]).
    pub fn into_spare(self) -> Vec<u8> {
        match self {
            PhotoPixels::Rgb8(img) => img.into_raw(),
            PhotoPixels::Rgb32F(_) => Vec::new(),
        }
    }
}

/// Decodes a photograph, 8-bit RGB files into `spare`'s memory (a caller decoding photograph
/// after photograph passes the last one's buffer back, [`PhotoPixels::into_spare`], which
/// saves the page faults of fresh memory per photograph), and its alpha channel as a mask
/// (8-bit, opaque = object, read as masks are: 128 and above) when it has one that hides some
/// pixel: background-removal tools write photographs whose transparent pixels still hold a
/// colour (often black) that is not the object's. An alpha channel that is opaque everywhere
/// is no mask.
pub fn read_photo_and_alpha(
    path: &Path,
    spare: Vec<u8>,
) -> Result<(PhotoPixels, Option<GrayImage>)> {
    check_complete(path)?;
    let mut r = open(path)?;
    r.limits(limits());
    let decoder = r.into_decoder().map_err(|e| decode_error(path, e))?;
    if decoder.color_type() != ColorType::Rgb8 {
        let img = DynamicImage::from_decoder(decoder).map_err(|e| decode_error(path, e))?;
        let alpha = if img.color().has_alpha() {
            let rgba = img.to_rgba8();
            let (w, h) = rgba.dimensions();
            let a: Vec<u8> = rgba.pixels().map(|p| p.0[3]).collect();
            a.iter()
                .any(|&v| v < 128)
                .then(|| GrayImage::from_raw(w, h, a).expect("one byte per pixel"))
        } else {
            None
        };
        return Ok((PhotoPixels::Rgb32F(img.into_rgb32f()), alpha));
    }
    let (w, h) = decoder.dimensions();
    let n = usize::try_from(decoder.total_bytes())
        .map_err(|_| Error::parse(path, Location::File, "image too large for this machine"))?;
    let mut buf = spare;
    buf.clear();
    buf.resize(n, 0);
    decoder
        .read_image(&mut buf)
        .map_err(|e| decode_error(path, e))?;
    Ok((
        PhotoPixels::Rgb8(image::RgbImage::from_raw(w, h, buf).expect("3 bytes per pixel")),
        None,
    ))
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
    .map_err(|e| Error::Internal(format!("cannot encode PNG: {e}")))?;
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
        .map_err(|e| Error::Internal(format!("cannot encode EXR: {e}")))?;
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
pub fn read_planar(path: &Path) -> Result<(crate::planar::Image, Depth)> {
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
        crate::planar::Image {
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
    Ok(mask_of(&read(path)?))
}

/// The lower-case extension of an image output, if it is one [`write_planar`] can write.
pub fn planar_output_format(path: &Path) -> Result<String> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "png" | "jpg" | "jpeg" | "exr" => Ok(ext),
        _ => Err(Error::parse(
            path,
            Location::File,
            "output format must be .png, .jpg, .jpeg or .exr",
        )),
    }
}

/// Writes an image in the format its extension names (png, jpg/jpeg, exr), 16-bit PNG when
/// `depth` is 16-bit, atomically.
pub fn write_planar(path: &Path, img: &crate::planar::Image, depth: Depth) -> Result<()> {
    let bytes = encode_planar(path, img, depth)?;
    super::write_atomic(path, &bytes)
}

/// [`write_planar`] through staging prepared before the work.
pub fn stage_planar(
    mut staged: super::Staged,
    path: &Path,
    img: &crate::planar::Image,
    depth: Depth,
) -> Result<()> {
    let bytes = encode_planar(path, img, depth)?;
    staged.write(path, &bytes)?;
    staged.commit()
}

fn encode_planar(path: &Path, img: &crate::planar::Image, depth: Depth) -> Result<Vec<u8>> {
    use image::{ImageBuffer, Luma, Rgb};
    let ext = planar_output_format(path)?;
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
    Ok(bytes)
}
