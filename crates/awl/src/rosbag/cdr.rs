//! The ROS 2 messages the importer reads, decoded from CDR (the OMG's Common Data Representation as
//! ROS 2 serialises it): a 4-byte encapsulation header (`00 01` little-endian, `00 00` big-endian,
//! two option bytes), then the fields in order, each primitive aligned to its size counted from the
//! end of the header; strings as a `u32` length (with the terminating NUL) and the bytes; sequences
//! as a `u32` count and the elements.
//!
//! Written here rather than taken from a serde-based CDR crate: the five layouts are short, and an
//! image's pixels are borrowed from the message buffer instead of copied into a `Vec` (a 640 x 480
//! depth frame is 600 kB; a bag holds thousands).

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

/// A decoding failure: what was being read and why (the caller adds the file and topic).
pub type CdrResult<T> = std::result::Result<T, String>;

/// A CDR buffer being read field by field.
pub struct CdrReader<'a> {
    buf: &'a [u8],
    pos: usize,
    little: bool,
}

impl<'a> CdrReader<'a> {
    /// A reader past the encapsulation header of `buf`.
    ///
    /// # Errors
    /// When the buffer is shorter than the header or its representation is not plain CDR
    /// (little- or big-endian; XCDR2 and parameter lists are not ROS 2's default).
    pub fn new(buf: &'a [u8]) -> CdrResult<Self> {
        let little = match buf.get(..2) {
            Some([0x00, 0x01]) => true,
            Some([0x00, 0x00]) => false,
            Some(h) => {
                return Err(format!("CDR encapsulation {:02x} {:02x} is not plain CDR (00 00 or 00 01)", h[0], h[1]));
            }
            None => return Err("message shorter than its 4-byte CDR header".into()),
        };
        if buf.len() < 4 {
            return Err("message shorter than its 4-byte CDR header".into());
        }
        Ok(Self { buf, pos: 4, little })
    }

    fn align(&mut self, n: usize) {
        let offset = self.pos - 4;
        self.pos += (n - offset % n) % n;
    }

    fn take(&mut self, n: usize, what: &str) -> CdrResult<&'a [u8]> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.buf.len());
        let Some(end) = end else {
            return Err(format!(
                "message ends inside `{what}` (needs {n} bytes at offset {}, has {})",
                self.pos,
                self.buf.len()
            ));
        };
        let bytes = &self.buf[self.pos..end];
        self.pos = end;
        Ok(bytes)
    }

    /// A `uint8` / `bool`.
    pub fn u8(&mut self, what: &str) -> CdrResult<u8> {
        Ok(self.take(1, what)?[0])
    }

    /// A `uint32`.
    pub fn u32(&mut self, what: &str) -> CdrResult<u32> {
        self.align(4);
        let b: [u8; 4] = self.take(4, what)?.try_into().map_err(|_| what.to_string())?;
        Ok(if self.little { u32::from_le_bytes(b) } else { u32::from_be_bytes(b) })
    }

    /// An `int32`.
    pub fn i32(&mut self, what: &str) -> CdrResult<i32> {
        Ok(self.u32(what)? as i32)
    }

    /// A `float64`.
    pub fn f64(&mut self, what: &str) -> CdrResult<f64> {
        self.align(8);
        let b: [u8; 8] = self.take(8, what)?.try_into().map_err(|_| what.to_string())?;
        Ok(if self.little { f64::from_le_bytes(b) } else { f64::from_be_bytes(b) })
    }

    /// A `string` (UTF-8; the terminating NUL dropped).
    pub fn string(&mut self, what: &str) -> CdrResult<String> {
        let n = self.u32(what)? as usize;
        let bytes = self.take(n, what)?;
        let bytes = bytes.strip_suffix(&[0]).unwrap_or(bytes);
        String::from_utf8(bytes.to_vec()).map_err(|_| format!("`{what}` is not UTF-8"))
    }

    /// A `uint8[]` sequence, borrowed.
    pub fn bytes(&mut self, what: &str) -> CdrResult<&'a [u8]> {
        let n = self.u32(what)? as usize;
        self.take(n, what)
    }

    /// A `float64[]` sequence.
    pub fn f64_seq(&mut self, what: &str) -> CdrResult<Vec<f64>> {
        let n = self.u32(what)? as usize;
        if n > self.buf.len() / 8 {
            return Err(format!("`{what}` claims {n} numbers, more than the message holds"));
        }
        (0..n).map(|_| self.f64(what)).collect()
    }

    /// A `float64[N]` array.
    pub fn f64_array<const N: usize>(&mut self, what: &str) -> CdrResult<[f64; N]> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(what)?;
        }
        Ok(out)
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    /// `stamp` (`builtin_interfaces/Time`: `sec` + `nanosec`), nanoseconds since the epoch.
    pub stamp_ns: i64,
    /// `frame_id`.
    pub frame_id: String,
}

fn header(r: &mut CdrReader<'_>) -> CdrResult<Header> {
    let sec = r.i32("header.stamp.sec")?;
    let nanosec = r.u32("header.stamp.nanosec")?;
    let frame_id = r.string("header.frame_id")?;
    Ok(Header { stamp_ns: i64::from(sec) * 1_000_000_000 + i64::from(nanosec), frame_id })
}

/// Only the header of a message that starts with one (every image and camera-info message).
///
/// # Errors
/// When the buffer is not CDR or ends inside the header.
pub fn decode_header(data: &[u8]) -> CdrResult<Header> {
    header(&mut CdrReader::new(data)?)
}

/// `sensor_msgs/msg/Image`, its pixels borrowed.
#[derive(Debug, Clone)]
pub struct Image<'a> {
    /// `header`.
    pub header: Header,
    /// `height`, pixels.
    pub height: u32,
    /// `width`, pixels.
    pub width: u32,
    /// `encoding` (`16UC1`, `32FC1`, `rgb8`, ...).
    pub encoding: String,
    /// `is_bigendian`.
    pub big_endian: bool,
    /// `step`: bytes per row.
    pub step: u32,
    /// `data`.
    pub data: &'a [u8],
}

/// Decodes a `sensor_msgs/msg/Image`.
///
/// # Errors
/// When the buffer is not CDR or ends early.
pub fn decode_image(data: &[u8]) -> CdrResult<Image<'_>> {
    let mut r = CdrReader::new(data)?;
    Ok(Image {
        header: header(&mut r)?,
        height: r.u32("height")?,
        width: r.u32("width")?,
        encoding: r.string("encoding")?,
        big_endian: r.u8("is_bigendian")? != 0,
        step: r.u32("step")?,
        data: r.bytes("data")?,
    })
}

/// `sensor_msgs/msg/CompressedImage`, its bytes borrowed.
#[derive(Debug, Clone)]
pub struct CompressedImage<'a> {
    /// `header`.
    pub header: Header,
    /// `format` (e.g. `rgb8; jpeg compressed bgr8`, `16UC1; compressedDepth png`).
    pub format: String,
    /// `data`: the compressed image.
    pub data: &'a [u8],
}

/// Decodes a `sensor_msgs/msg/CompressedImage`.
///
/// # Errors
/// When the buffer is not CDR or ends early.
pub fn decode_compressed_image(data: &[u8]) -> CdrResult<CompressedImage<'_>> {
    let mut r = CdrReader::new(data)?;
    Ok(CompressedImage { header: header(&mut r)?, format: r.string("format")?, data: r.bytes("data")? })
}

/// The fields of `sensor_msgs/msg/CameraInfo` the importer uses.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// `header`.
    pub header: Header,
    /// `height`, pixels.
    pub height: u32,
    /// `width`, pixels.
    pub width: u32,
    /// `distortion_model` (`plumb_bob`, `rational_polynomial`, `equidistant`, ...).
    pub distortion_model: String,
    /// `d`: the distortion coefficients (`plumb_bob`: k1, k2, t1, t2, k3).
    pub d: Vec<f64>,
    /// `k`: the 3x3 intrinsic matrix, row-major, pixels.
    pub k: [f64; 9],
}

/// Decodes a `sensor_msgs/msg/CameraInfo` (up to `k`; the rest is not needed).
///
/// # Errors
/// When the buffer is not CDR or ends early.
pub fn decode_camera_info(data: &[u8]) -> CdrResult<CameraInfo> {
    let mut r = CdrReader::new(data)?;
    Ok(CameraInfo {
        header: header(&mut r)?,
        height: r.u32("height")?,
        width: r.u32("width")?,
        distortion_model: r.string("distortion_model")?,
        d: r.f64_seq("d")?,
        k: r.f64_array::<9>("k")?,
    })
}

/// One `geometry_msgs/msg/TransformStamped` of a `tf2_msgs/msg/TFMessage`.
#[derive(Debug, Clone, PartialEq)]
pub struct Transform {
    /// `header` (`frame_id`: the parent frame).
    pub header: Header,
    /// `child_frame_id`.
    pub child_frame_id: String,
    /// `transform`: translation (metres) and rotation (quaternion `x, y, z, w`), as given.
    pub translation: [f64; 3],
    /// The rotation quaternion `[x, y, z, w]`, as given (not normalised).
    pub rotation_xyzw: [f64; 4],
}

impl Transform {
    /// `parent_from_child`, the quaternion normalised.
    ///
    /// # Errors
    /// When a number is not finite or the quaternion's norm is more than 1e-3 away from 1.
    pub fn parent_from_child(&self) -> CdrResult<Isometry3<f64>> {
        let [x, y, z, w] = self.rotation_xyzw;
        let q = Quaternion::new(w, x, y, z);
        let norm = q.norm();
        if !self.translation.iter().chain(&self.rotation_xyzw).all(|v| v.is_finite()) || (norm - 1.0).abs() > 1e-3 {
            return Err(format!(
                "transform `{}` -> `{}`: translation {:?}, quaternion {:?} (norm {norm}) is not a rigid transform",
                self.header.frame_id, self.child_frame_id, self.translation, self.rotation_xyzw
            ));
        }
        let [tx, ty, tz] = self.translation;
        Ok(Isometry3::from_parts(Translation3::new(tx, ty, tz), UnitQuaternion::from_quaternion(q)))
    }
}

/// Decodes a `tf2_msgs/msg/TFMessage` (`/tf`, `/tf_static`).
///
/// # Errors
/// When the buffer is not CDR or ends early.
pub fn decode_tf_message(data: &[u8]) -> CdrResult<Vec<Transform>> {
    let mut r = CdrReader::new(data)?;
    let n = r.u32("transforms")? as usize;
    if n > data.len() / 60 {
        return Err(format!("`transforms` claims {n} transforms, more than the message holds"));
    }
    (0..n)
        .map(|_| {
            let header = header(&mut r)?;
            let child_frame_id = r.string("child_frame_id")?;
            let translation = r.f64_array::<3>("transform.translation")?;
            let rotation_xyzw = r.f64_array::<4>("transform.rotation")?;
            Ok(Transform { header, child_frame_id, translation, rotation_xyzw })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A little-endian CDR writer for the tests (the layouts by hand, as ROS 2 writes them).
    struct W(Vec<u8>);
    impl W {
        fn new() -> Self {
            Self(vec![0, 1, 0, 0])
        }
        fn align(&mut self, n: usize) {
            while !(self.0.len() - 4).is_multiple_of(n) {
                self.0.push(0);
            }
        }
        fn u32(&mut self, v: u32) {
            self.align(4);
            self.0.extend(v.to_le_bytes());
        }
        fn f64(&mut self, v: f64) {
            self.align(8);
            self.0.extend(v.to_le_bytes());
        }
        fn string(&mut self, s: &str) {
            self.u32(s.len() as u32 + 1);
            self.0.extend(s.as_bytes());
            self.0.push(0);
        }
    }

    #[test]
    fn tf_message_with_alignment_padding() {
        let mut w = W::new();
        w.u32(1);
        w.u32(12);
        w.u32(500);
        w.string("map");
        w.string("base_link"); // 10 bytes: the translation's f64 needs padding after it
        for v in [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0] {
            w.f64(v);
        }
        let tf = decode_tf_message(&w.0).expect("decode");
        assert_eq!(tf.len(), 1);
        assert_eq!(tf[0].header.stamp_ns, 12_000_000_500);
        assert_eq!((tf[0].header.frame_id.as_str(), tf[0].child_frame_id.as_str()), ("map", "base_link"));
        assert_eq!(tf[0].translation, [1.0, 2.0, 3.0]);
        assert_eq!(tf[0].parent_from_child().expect("rigid").translation.vector.z, 3.0);
        let err = decode_tf_message(&w.0[..w.0.len() - 3]).expect_err("truncated");
        assert!(err.contains("transform.rotation"), "{err}");
    }

    #[test]
    fn image_pixels_are_borrowed_and_bad_headers_refused() {
        let mut w = W::new();
        w.u32(1);
        w.u32(2);
        w.string("cam");
        w.u32(1);
        w.u32(2);
        w.string("16UC1");
        w.0.push(0);
        w.u32(4);
        w.u32(4);
        w.0.extend([1, 0, 2, 0]);
        let image = decode_image(&w.0).expect("decode");
        assert_eq!((image.width, image.height, image.step, image.encoding.as_str()), (2, 1, 4, "16UC1"));
        assert_eq!(image.data, &[1, 0, 2, 0]);
        assert!(CdrReader::new(&[0, 7, 0, 0]).is_err());
        assert!(CdrReader::new(&[0]).is_err());
    }
}
