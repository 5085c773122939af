//! `sensor_msgs/msg/PointCloud2`: a header, the cloud's size, a list of named fields (offset,
//! datatype, count) inside each `point_step`-byte point, and the point bytes. Drivers differ in
//! the field layout (Velodyne: x y z intensity ring time; Ouster: x y z t(ns) reflectivity ring
//! ...; Hesai/Livox: absolute `timestamp` doubles), so the decoder reads whatever layout the
//! message declares: x y z as float32 or float64, optional intensity, ring/channel and per-point
//! time, in either byte order.

use super::msgs::{read_header, write_header};
use super::{CdrError, Reader, Writer};
use crate::sample::Cloud;

/// PointField datatypes (sensor_msgs/msg/PointField constants).
const INT8: u8 = 1;
const UINT8: u8 = 2;
const INT16: u8 = 3;
const UINT16: u8 = 4;
const INT32: u8 = 5;
const UINT32: u8 = 6;
const FLOAT32: u8 = 7;
const FLOAT64: u8 = 8;

/// Per-point times above this are absolute (Unix seconds), not relative to the stamp.
const ABSOLUTE_TIME_S: f64 = 1.0e6;

#[derive(Clone, Copy, Debug)]
struct Field {
    offset: usize,
    datatype: u8,
}

fn size_of(datatype: u8) -> Option<usize> {
    match datatype {
        INT8 | UINT8 => Some(1),
        INT16 | UINT16 => Some(2),
        INT32 | UINT32 | FLOAT32 => Some(4),
        FLOAT64 => Some(8),
        _ => None,
    }
}

/// Reads one field of one point as f64 (the layout was checked, so the bytes are there).
fn read(point: &[u8], f: Field, big: bool) -> f64 {
    let n = size_of(f.datatype).unwrap_or(1);
    let mut b = [0u8; 8];
    b[..n].copy_from_slice(&point[f.offset..f.offset + n]);
    if big {
        b[..n].reverse();
    }
    match f.datatype {
        INT8 => b[0] as i8 as f64,
        UINT8 => b[0] as f64,
        INT16 => i16::from_le_bytes([b[0], b[1]]) as f64,
        UINT16 => u16::from_le_bytes([b[0], b[1]]) as f64,
        INT32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        UINT32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        FLOAT32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        _ => f64::from_le_bytes(b),
    }
}

/// Decodes a PointCloud2. Points with a non-finite coordinate are dropped and counted in
/// [`Cloud::dropped_non_finite`]; a layout that does not fit the data is an error.
pub fn decode_point_cloud2(msg: &[u8]) -> Result<Cloud, CdrError> {
    let mut r = Reader::new(msg)?;
    let (stamp_s, frame_id) = read_header(&mut r)?;
    let height = r.u32("height")? as usize;
    let width = r.u32("width")? as usize;
    // A PointField is at least a 4-byte string length + offset + datatype + count.
    let n_fields = r.seq_len(13, "fields")?;
    let mut fields = Vec::with_capacity(n_fields);
    for _ in 0..n_fields {
        let name = r.string("field.name")?;
        let offset = r.u32("field.offset")? as usize;
        let datatype = r.u8("field.datatype")?;
        let count = r.u32("field.count")?;
        fields.push((name, offset, datatype, count));
    }
    let big = r.bool("is_bigendian")?;
    let point_step = r.u32("point_step")? as usize;
    let row_step = r.u32("row_step")? as usize;
    let data = r.bytes("data")?;
    let _is_dense = r.bool("is_dense")?;

    let invalid = |why: String| CdrError::Invalid {
        what: "PointCloud2",
        why,
    };
    let find = |names: &[&str]| -> Result<Option<Field>, CdrError> {
        let Some((name, offset, datatype, _)) =
            fields.iter().find(|(n, ..)| names.contains(&n.as_str()))
        else {
            return Ok(None);
        };
        let size = size_of(*datatype)
            .ok_or_else(|| invalid(format!("field {name}: unknown datatype {datatype}")))?;
        if offset.saturating_add(size) > point_step {
            return Err(invalid(format!(
                "field {name} at {offset}+{size} outside point_step {point_step}"
            )));
        }
        Ok(Some(Field {
            offset: *offset,
            datatype: *datatype,
        }))
    };
    let axis = |n: &str| -> Result<Field, CdrError> {
        let f = find(&[n])?.ok_or_else(|| invalid(format!("no {n} field")))?;
        if f.datatype != FLOAT32 && f.datatype != FLOAT64 {
            return Err(invalid(format!(
                "{n} is datatype {}, not float32/64",
                f.datatype
            )));
        }
        Ok(f)
    };
    let (fx, fy, fz) = (axis("x")?, axis("y")?, axis("z")?);
    let f_intensity = find(&["intensity"])?;
    let f_ring = find(&["ring", "channel"])?;
    let f_time = find(&["t", "time", "timestamp", "time_stamp", "offset_time"])?;

    let n = width
        .checked_mul(height)
        .ok_or_else(|| invalid("size overflows".into()))?;
    if point_step == 0 && n > 0 {
        return Err(invalid("point_step 0".into()));
    }
    let row_len = width
        .checked_mul(point_step)
        .ok_or_else(|| invalid("size overflows".into()))?;
    if row_step < row_len {
        return Err(invalid(format!(
            "row_step {row_step} < width*point_step {row_len}"
        )));
    }
    let need = row_step
        .checked_mul(height.saturating_sub(1))
        .and_then(|v| v.checked_add(row_len));
    if height > 0 && need.is_none_or(|need| need > data.len()) {
        return Err(invalid(format!(
            "{height}x{width} points of {point_step} bytes (row_step {row_step}) need more than the {} data bytes",
            data.len()
        )));
    }

    let mut cloud = Cloud {
        stamp_s,
        frame_id,
        points: Vec::with_capacity(n),
        intensity: f_intensity.map(|_| Vec::with_capacity(n)),
        ring: f_ring.map(|_| Vec::with_capacity(n)),
        time_s: f_time.map(|_| Vec::with_capacity(n)),
        dropped_non_finite: 0,
    };
    for row in 0..height {
        let row_bytes = &data[row * row_step..row * row_step + row_len];
        for p in row_bytes.chunks_exact(point_step) {
            let xyz = [read(p, fx, big), read(p, fy, big), read(p, fz, big)];
            if !xyz.iter().all(|v| v.is_finite()) {
                cloud.dropped_non_finite += 1;
                continue;
            }
            cloud.points.push(xyz.map(|v| v as f32));
            if let (Some(out), Some(f)) = (cloud.intensity.as_mut(), f_intensity) {
                out.push(read(p, f, big) as f32);
            }
            if let (Some(out), Some(f)) = (cloud.ring.as_mut(), f_ring) {
                out.push(read(p, f, big).clamp(0.0, u16::MAX as f64) as u16);
            }
            if let (Some(out), Some(f)) = (cloud.time_s.as_mut(), f_time) {
                let v = read(p, f, big);
                let rel = match f.datatype {
                    // Integer times are nanoseconds after the stamp (Ouster `t`).
                    FLOAT32 | FLOAT64 if v > ABSOLUTE_TIME_S => v - stamp_s,
                    FLOAT32 | FLOAT64 => v,
                    _ => v * 1e-9,
                };
                out.push(rel as f32);
            }
        }
    }
    Ok(cloud)
}

/// Encodes a cloud as an unorganised (height 1) little-endian PointCloud2 with float32 x y z,
/// and float32 `intensity`, uint16 `ring` and float32 `time` fields when the cloud has them.
pub fn encode_point_cloud2(c: &Cloud) -> Vec<u8> {
    let mut fields: Vec<(&str, u32, u8)> =
        vec![("x", 0, FLOAT32), ("y", 4, FLOAT32), ("z", 8, FLOAT32)];
    let mut step = 12u32;
    if c.intensity.is_some() {
        fields.push(("intensity", step, FLOAT32));
        step += 4;
    }
    if c.ring.is_some() {
        fields.push(("ring", step, UINT16));
        step += 2;
    }
    if c.time_s.is_some() {
        step = step.next_multiple_of(4);
        fields.push(("time", step, FLOAT32));
        step += 4;
    }
    let step = step.next_multiple_of(4);
    let mut data = Vec::with_capacity(c.points.len() * step as usize);
    for (i, p) in c.points.iter().enumerate() {
        let start = data.len();
        data.resize(start + step as usize, 0);
        let point = &mut data[start..];
        for (k, v) in p.iter().enumerate() {
            point[4 * k..4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
        for (name, off, _) in &fields[3..] {
            let off = *off as usize;
            match *name {
                "intensity" => {
                    let v = c
                        .intensity
                        .as_ref()
                        .and_then(|v| v.get(i))
                        .copied()
                        .unwrap_or(0.0);
                    point[off..off + 4].copy_from_slice(&v.to_le_bytes());
                }
                "ring" => {
                    let v = c.ring.as_ref().and_then(|v| v.get(i)).copied().unwrap_or(0);
                    point[off..off + 2].copy_from_slice(&v.to_le_bytes());
                }
                _ => {
                    let v = c
                        .time_s
                        .as_ref()
                        .and_then(|v| v.get(i))
                        .copied()
                        .unwrap_or(0.0);
                    point[off..off + 4].copy_from_slice(&v.to_le_bytes());
                }
            }
        }
    }
    let mut w = Writer::new();
    write_header(&mut w, c.stamp_s, &c.frame_id);
    w.u32(1);
    w.u32(c.points.len() as u32);
    w.u32(fields.len() as u32);
    for (name, off, dt) in &fields {
        w.string(name);
        w.u32(*off);
        w.u8(*dt);
        w.u32(1);
    }
    w.bool(false);
    w.u32(step);
    w.u32(step * c.points.len() as u32);
    w.bytes(&data);
    w.bool(true);
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> Cloud {
        Cloud {
            stamp_s: 100.5,
            frame_id: "velodyne".into(),
            points: vec![[1.0, 2.0, 3.0], [-4.0, 5.5, 0.25]],
            intensity: Some(vec![10.0, 200.0]),
            ring: Some(vec![3, 15]),
            time_s: Some(vec![0.0, 0.05]),
            dropped_non_finite: 0,
        }
    }

    #[test]
    fn round_trip_with_all_fields() {
        let c = cloud();
        assert_eq!(decode_point_cloud2(&encode_point_cloud2(&c)).unwrap(), c);
        let bare = Cloud {
            intensity: None,
            ring: None,
            time_s: None,
            ..c
        };
        assert_eq!(
            decode_point_cloud2(&encode_point_cloud2(&bare)).unwrap(),
            bare
        );
    }

    #[test]
    fn nans_are_dropped_and_counted() {
        let mut c = cloud();
        c.points[0][1] = f32::NAN;
        let d = decode_point_cloud2(&encode_point_cloud2(&c)).unwrap();
        assert_eq!(d.points, vec![[-4.0, 5.5, 0.25]]);
        assert_eq!(d.dropped_non_finite, 1);
        assert_eq!(d.ring, Some(vec![15]));
    }

    #[test]
    fn every_truncation_is_an_error() {
        let m = encode_point_cloud2(&cloud());
        for n in 0..m.len() {
            assert!(decode_point_cloud2(&m[..n]).is_err(), "prefix {n} decoded");
        }
    }
}
