//! Camera image files to RGB. A damaged JPEG must be an error: the lenient decoders fill what
//! they cannot read with grey and return an image that would be encoded, rendered against and
//! scored as if the camera had seen it.

use image::RgbImage;
use zune_jpeg::JpegDecoder;
use zune_jpeg::zune_core::bytestream::ZCursor;
use zune_jpeg::zune_core::colorspace::ColorSpace;
use zune_jpeg::zune_core::options::DecoderOptions;

/// Decodes a JPEG or PNG file's bytes to RGB; the message says what is wrong.
pub fn decode_rgb(bytes: &[u8]) -> Result<RgbImage, String> {
    if bytes.starts_with(&[0xFF, 0xD8]) {
        decode_jpeg_strict(bytes)
    } else {
        image::load_from_memory(bytes)
            .map(|image| image.into_rgb8())
            .map_err(|error| error.to_string())
    }
}

/// A JPEG decoded in the decoder's strict mode: corrupt entropy-coded data, a marker where
/// none belongs or data that ends early is an error, not grey rows.
fn decode_jpeg_strict(bytes: &[u8]) -> Result<RgbImage, String> {
    // A file cut short may still parse to its last whole block: a whole one ends with the
    // end-of-image marker.
    let tail = &bytes[bytes.len().saturating_sub(32)..];
    if !tail.windows(2).any(|w| w == [0xFF, 0xD9]) {
        return Err(format!(
            "truncated JPEG: {} bytes without the end-of-image marker",
            bytes.len()
        ));
    }
    let options = DecoderOptions::default()
        .set_strict_mode(true)
        .jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut decoder = JpegDecoder::new_with_options(ZCursor::new(bytes), options);
    let pixels = decoder
        .decode()
        .map_err(|error| format!("corrupt JPEG: {error}"))?;
    let info = decoder
        .info()
        .ok_or_else(|| "corrupt JPEG: no frame header".to_string())?;
    let (width, height) = (u32::from(info.width), u32::from(info.height));
    RgbImage::from_raw(width, height, pixels).ok_or_else(|| {
        format!("corrupt JPEG: decoded data does not fill its {width}x{height} frame")
    })
}
