//! Image files as replay reads them: the whole file checked (a truncated JPEG is an error,
//! not a grey image), RGB for the overlays, and the luma bytes of a grey file.

use super::{ReplayError, io_err};
use image::RgbImage;
use std::path::Path;

/// Loads an image file as RGB8.
///
/// A JPEG must end with its end-of-image marker: the decoder fills a truncated one with grey
/// and says nothing, which would replay a different image than the file's. (A truncated PNG
/// fails its own checks.)
pub fn load_rgb(path: &Path) -> Result<RgbImage, ReplayError> {
    load_image(path).map(|i| i.rgb)
}

/// An image file as replay uses it: RGB (for the overlays, and the flies unless both images
/// of a pair are grey), and its luma bytes if the file has no colour.
pub struct LoadedImage {
    pub rgb: RgbImage,
    /// `Some`: the file is grey (a grey camera's frame, or a colour camera's luma), and a pair
    /// of two grey files is compared in grey, as the daemon compares a grey camera's frames.
    pub luma: Option<Vec<u8>>,
}

/// [`load_rgb`], keeping the luma of a grey file.
pub fn load_image(path: &Path) -> Result<LoadedImage, ReplayError> {
    let name = || path.display().to_string();
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    // The content says what it is; failing that, the extension (so that a damaged PNG is
    // reported by the PNG decoder).
    let format = image::guess_format(&bytes)
        .or_else(|_| image::ImageFormat::from_path(path))
        .map_err(|source| ReplayError::Image {
            path: name(),
            source,
        })?;
    if format == image::ImageFormat::Jpeg {
        let end = bytes.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
        if !bytes[..end].ends_with(&[0xFF, 0xD9]) {
            return Err(ReplayError::Truncated {
                path: name(),
                what: "JPEG without its end-of-image marker (FF D9)",
            });
        }
    }
    let image = image::load_from_memory_with_format(&bytes, format).map_err(|source| {
        ReplayError::Image {
            path: name(),
            source,
        }
    })?;
    let luma = (!image.color().has_color()).then(|| image.to_luma8().into_raw());
    Ok(LoadedImage {
        rgb: image.to_rgb8(),
        luma,
    })
}
