//! A* on a 300 x 300 planning window (0.2 m cells, 60 m x 60 m) with realistic obstacles:
//! inflated tree trunks and bushes, two long walls with gaps, cost fields around obstacles and a
//! patch of unknown cells. Goal: ≤ 3 ms per plan (the source system needed 287 ms mean).
//! With `--features baseline`, the `pathfinding` crate's A* on the same grid for comparison.

use criterion::{criterion_group, criterion_main, Criterion};
use planning::{CellXY, PlanGrid, Planner};

/// A deterministic park-like window.
fn park_grid() -> PlanGrid {
    let (w, h, s) = (300u32, 300u32, 0.2);
    let mut g = PlanGrid::new(w, h, s, (-30.0, -30.0));
    let mut state = 0x5eed_u64;
    let mut rnd = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    // 80 round obstacles, radius 0.2-1.5 m, inflated by 0.4 m, with a decaying penalty ring.
    for _ in 0..80 {
        let (cx, cy, r) = (rnd() * 300.0, rnd() * 300.0, (0.2 + 1.3 * rnd()) / s + 2.0);
        let ring = r + 4.0;
        for y in (cy - ring) as i64..=(cy + ring) as i64 {
            for x in (cx - ring) as i64..=(cx + ring) as i64 {
                let d = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt();
                if d <= r {
                    g.set_blocked(x, y);
                } else if d <= ring && g.is_free(x, y) {
                    g.set(x, y, (0.5 * (ring - d) / 4.0) as f32, false);
                }
            }
        }
    }
    // Two walls with gaps (a fence line and a building edge).
    for x in 0..300i64 {
        if !(60..70).contains(&x) && !(200..215).contains(&x) {
            g.set_blocked(x, 100);
            g.set_blocked(x, 101);
        }
    }
    for y in 120..280i64 {
        if !(240..250).contains(&y) {
            g.set_blocked(180, y);
        }
    }
    // Unobserved area behind the building.
    for y in 200..260i64 {
        for x in 220..290i64 {
            if g.is_free(x, y) {
                g.set(x, y, 0.1, true);
            }
        }
    }
    for c in [(150, 150), (5, 5), (294, 294)] {
        for y in c.1 - 3..=c.1 + 3 {
            for x in c.0 - 3..=c.0 + 3 {
                g.set(x, y, 0.0, false);
            }
        }
    }
    g
}

fn bench(c: &mut Criterion) {
    let grid = park_grid();
    let mut planner = Planner::new();
    let cases = [
        (
            "centre_to_corner",
            CellXY::new(150, 150),
            CellXY::new(294, 294),
        ),
        ("corner_to_corner", CellXY::new(5, 5), CellXY::new(294, 294)),
    ];
    for (name, start, goal) in cases {
        let path = planner
            .plan(&grid, start, goal)
            .expect("bench grid has a path");
        eprintln!(
            "{name}: length {:.2} m, cost {:.2} m, {} expansions",
            path.length_m, path.cost_m, path.expansions
        );
        c.bench_function(&format!("astar_300x300_{name}"), |b| {
            b.iter(|| planner.plan(&grid, start, goal).map(|p| p.cost_m))
        });
        #[cfg(feature = "baseline")]
        c.bench_function(&format!("pathfinding_300x300_{name}"), |b| {
            b.iter(|| planning::baseline::pathfinding_astar(&grid, start, goal).map(|p| p.1))
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
