//! The test frames of the V4L2 smoke test, shared by the guest program (which writes and
//! checks them) and the host test (which checks what came back through the results share).
//!
//! A frame is YUYV 64x48 (6144 bytes): `FLYD`, the camera id, the frame index (u32 LE), then
//! bytes that depend on position, camera and index, so a frame that is torn, stale, or from the
//! other camera does not match.

pub const WIDTH: u32 = 64;
pub const HEIGHT: u32 = 48;
/// YUYV: 2 bytes per pixel.
pub const FRAME_LEN: usize = (WIDTH * HEIGHT * 2) as usize;
const MAGIC: &[u8; 4] = b"FLYD";
const HEADER_LEN: usize = 9;

pub fn frame(camera: u8, index: u32) -> Vec<u8> {
    let mut frame = Vec::with_capacity(FRAME_LEN);
    frame.extend_from_slice(MAGIC);
    frame.push(camera);
    frame.extend_from_slice(&index.to_le_bytes());
    for i in HEADER_LEN..FRAME_LEN {
        frame.push(body_byte(camera, index, i));
    }
    frame
}

fn body_byte(camera: u8, index: u32, position: usize) -> u8 {
    let mixed = (position as u32)
        .wrapping_mul(31)
        .wrapping_add(index.wrapping_mul(7))
        .wrapping_add(u32::from(camera).wrapping_mul(101));
    mixed.to_le_bytes()[0]
}

/// The (camera, index) of a frame that is exactly `frame(camera, index)`, else why not.
pub fn identify(bytes: &[u8]) -> Result<(u8, u32), String> {
    if bytes.len() != FRAME_LEN {
        return Err(format!("{} bytes, expected {FRAME_LEN}", bytes.len()));
    }
    if &bytes[..4] != MAGIC {
        return Err(format!("header {:02x?} is not FLYD", &bytes[..4]));
    }
    let camera = bytes[4];
    let index = u32::from_le_bytes([bytes[5], bytes[6], bytes[7], bytes[8]]);
    match (HEADER_LEN..FRAME_LEN).find(|&i| bytes[i] != body_byte(camera, index, i)) {
        None => Ok((camera, index)),
        Some(i) => Err(format!(
            "camera {camera} frame {index}: byte {i} is {:#04x}, expected {:#04x}",
            bytes[i],
            body_byte(camera, index, i)
        )),
    }
}
