//! Polygon geometry of zones (keep-out and slow), in a planar frame, metres: whether a point is
//! inside, how far it is from the edge, and whether a polygon is usable at all. The station
//! checks goals and draws with it; the robot plans and caps speed with it.
//!
//! Polygons are lists of corners in order, not closed (the last corner joins the first),
//! either orientation.

/// Why a polygon is not usable as a zone.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PolygonError {
    /// Fewer than 3 corners, or more than [`crate::command::MAX_ZONE_CORNERS`].
    #[error("{0} corners: a zone needs 3 to {max}", max = crate::command::MAX_ZONE_CORNERS)]
    Corners(usize),
    /// A corner is NaN or infinite.
    #[error("a corner is not finite")]
    NotFinite,
    /// The corners enclose no area (all on one line, or repeated).
    #[error("the corners enclose no area")]
    NoArea,
    /// Two edges cross.
    #[error("edges {0} and {1} cross")]
    SelfCrossing(usize, usize),
}

/// Checks that `poly` is a simple polygon with an area.
pub fn check_polygon(poly: &[(f64, f64)]) -> Result<(), PolygonError> {
    let n = poly.len();
    if !(3..=crate::command::MAX_ZONE_CORNERS).contains(&n) {
        return Err(PolygonError::Corners(n));
    }
    if poly.iter().any(|p| !(p.0.is_finite() && p.1.is_finite())) {
        return Err(PolygonError::NotFinite);
    }
    if area_m2(poly) < 1e-6 {
        return Err(PolygonError::NoArea);
    }
    for i in 0..n {
        for j in i + 1..n {
            // Neighbouring edges share a corner, which is not a crossing.
            if j == i + 1 || (i == 0 && j == n - 1) {
                continue;
            }
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            let (c, d) = (poly[j], poly[(j + 1) % n]);
            if segments_cross(a, b, c, d) {
                return Err(PolygonError::SelfCrossing(i, j));
            }
        }
    }
    Ok(())
}

fn cross(o: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
}

/// Whether segments ab and cd cross or touch.
fn segments_cross(a: (f64, f64), b: (f64, f64), c: (f64, f64), d: (f64, f64)) -> bool {
    let (d1, d2) = (cross(c, d, a), cross(c, d, b));
    let (d3, d4) = (cross(a, b, c), cross(a, b, d));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    let on = |p: (f64, f64), q: (f64, f64), r: (f64, f64), c: f64| {
        c.abs() < 1e-12
            && r.0 >= p.0.min(q.0)
            && r.0 <= p.0.max(q.0)
            && r.1 >= p.1.min(q.1)
            && r.1 <= p.1.max(q.1)
    };
    on(c, d, a, d1) || on(c, d, b, d2) || on(a, b, c, d3) || on(a, b, d, d4)
}

/// Area enclosed by the polygon, square metres (shoelace formula).
pub fn area_m2(poly: &[(f64, f64)]) -> f64 {
    let n = poly.len();
    let twice: f64 = (0..n)
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            a.0 * b.1 - b.0 * a.1
        })
        .sum();
    0.5 * twice.abs()
}

/// Whether `p` lies inside the polygon (even-odd rule; a point on the edge may go either way).
pub fn contains(poly: &[(f64, f64)], p: (f64, f64)) -> bool {
    let n = poly.len();
    let mut inside = false;
    let mut j = n.wrapping_sub(1);
    for i in 0..n {
        let (a, b) = (poly[i], poly[j]);
        if (a.1 > p.1) != (b.1 > p.1) && p.0 < (b.0 - a.0) * (p.1 - a.1) / (b.1 - a.1) + a.0 {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// Distance from `p` to the segment ab, metres.
pub fn segment_distance_m(a: (f64, f64), b: (f64, f64), p: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 {
        (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a.0 + t * dx - p.0).hypot(a.1 + t * dy - p.1)
}

/// Distance from `p` to the polygon's edge, metres (the same inside and outside).
pub fn edge_distance_m(poly: &[(f64, f64)], p: (f64, f64)) -> f64 {
    let n = poly.len();
    (0..n)
        .map(|i| segment_distance_m(poly[i], poly[(i + 1) % n], p))
        .fold(f64::INFINITY, f64::min)
}

/// Signed distance from `p` to the polygon: negative inside, positive outside, metres.
pub fn signed_distance_m(poly: &[(f64, f64)], p: (f64, f64)) -> f64 {
    let d = edge_distance_m(poly, p);
    if contains(poly, p) {
        -d
    } else {
        d
    }
}

/// Axis-aligned bounds ((x_min, y_min), (x_max, y_max)) of the polygon.
pub fn bounds(poly: &[(f64, f64)]) -> ((f64, f64), (f64, f64)) {
    poly.iter().fold(
        (
            (f64::INFINITY, f64::INFINITY),
            (f64::NEG_INFINITY, f64::NEG_INFINITY),
        ),
        |((x0, y0), (x1, y1)), p| ((x0.min(p.0), y0.min(p.1)), (x1.max(p.0), y1.max(p.1))),
    )
}

/// Length of the part of the segment ab inside the polygon, metres (sampled every `step_m`):
/// how much of a straight line a zone covers.
pub fn length_inside_m(poly: &[(f64, f64)], a: (f64, f64), b: (f64, f64), step_m: f64) -> f64 {
    let len = (b.0 - a.0).hypot(b.1 - a.1);
    let n = ((len / step_m.max(1e-3)).ceil() as usize).max(1);
    let inside = (0..n)
        .filter(|k| {
            let t = (*k as f64 + 0.5) / n as f64;
            contains(poly, (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)))
        })
        .count();
    len * inside as f64 / n as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> Vec<(f64, f64)> {
        vec![(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 4.0)]
    }

    #[test]
    fn inside_outside_and_distances() {
        let sq = square();
        assert!(contains(&sq, (1.0, 1.0)));
        assert!(!contains(&sq, (5.0, 1.0)));
        assert!((signed_distance_m(&sq, (1.0, 2.0)) + 1.0).abs() < 1e-12);
        assert!((signed_distance_m(&sq, (6.0, 2.0)) - 2.0).abs() < 1e-12);
        assert!((area_m2(&sq) - 16.0).abs() < 1e-12);
        assert_eq!(bounds(&sq), ((0.0, 0.0), (4.0, 4.0)));
        let l = length_inside_m(&sq, (-2.0, 2.0), (10.0, 2.0), 0.01);
        assert!((l - 4.0).abs() < 0.02, "{l}");
        // Clockwise works the same.
        let cw: Vec<_> = sq.iter().rev().copied().collect();
        assert!(contains(&cw, (3.9, 3.9)));
    }

    #[test]
    fn unusable_polygons_are_refused() {
        assert_eq!(check_polygon(&square()), Ok(()));
        assert_eq!(
            check_polygon(&[(0.0, 0.0), (1.0, 1.0)]),
            Err(PolygonError::Corners(2))
        );
        assert_eq!(
            check_polygon(&[(0.0, 0.0), (1.0, 1.0), (2.0, 2.0)]),
            Err(PolygonError::NoArea)
        );
        assert_eq!(
            check_polygon(&[(0.0, 0.0), (f64::NAN, 1.0), (2.0, 0.0)]),
            Err(PolygonError::NotFinite)
        );
        // A bow tie.
        assert!(matches!(
            check_polygon(&[(0.0, 0.0), (3.0, 2.0), (3.0, 0.0), (0.0, 1.0)]),
            Err(PolygonError::SelfCrossing(..))
        ));
    }
}
