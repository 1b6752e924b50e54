//! Opaque solids from level sets: `Solid::first_hit` against analytic signed distance fields
//! (sphere, box, plane) built in memory, the corpus's level-set sphere, and object transforms.
#![allow(clippy::unwrap_used, clippy::expect_used)]

// Only `corpus_dir` is used here.
#[allow(unused_imports)]
use crate::common;

use rand::{Rng, SeedableRng};
use umbra::glam::DVec3;
use umbra::internals::solid::Solid;
use umbra::internals::tree::TreeBuilder;
use umbra::internals::xform::Xform;
use umbra::Ray;

/// Narrow-band half width (voxels) and background of the analytic level sets.
const BAND: f64 = 3.0;

/// A level set of `phi` (index space, voxel units) over the index box `[lo, hi]`: voxels with
/// `|phi| < BAND` are set, interior voxels of a block that also holds band voxels are set to
/// `-BAND`, blocks entirely inside are `-BAND` 8^3 tiles (as OpenVDB fills interiors), the
/// rest is the background `BAND`. World = `voxel * index + offset`.
fn level_set(
    phi: impl Fn(DVec3) -> f64,
    lo: [i32; 3],
    hi: [i32; 3],
    voxel: f64,
    offset: [f64; 3],
) -> (Solid, usize) {
    let mut b = TreeBuilder::new(BAND as f32);
    let block = |c: i32| c.div_euclid(8);
    let mut tiles = 0;
    for bx in block(lo[0])..=block(hi[0]) {
        for by in block(lo[1])..=block(hi[1]) {
            for bz in block(lo[2])..=block(hi[2]) {
                let o = [bx * 8, by * 8, bz * 8];
                let mut vals = Vec::with_capacity(512);
                for i in 0..8 {
                    for j in 0..8 {
                        for k in 0..8 {
                            let ijk = [o[0] + i, o[1] + j, o[2] + k];
                            let p = DVec3::new(ijk[0].into(), ijk[1].into(), ijk[2].into());
                            vals.push((ijk, phi(p)));
                        }
                    }
                }
                if vals.iter().all(|&(_, v)| v <= -BAND) {
                    b.tile(o, 3, -BAND as f32);
                    tiles += 1;
                } else if vals.iter().any(|&(_, v)| v.abs() < BAND) {
                    for &(ijk, v) in &vals {
                        if v < BAND {
                            b.set(ijk, v.max(-BAND) as f32);
                        }
                    }
                }
            }
        }
    }
    let m = [
        [voxel, 0.0, 0.0, offset[0]],
        [0.0, voxel, 0.0, offset[1]],
        [0.0, 0.0, voxel, offset[2]],
    ];
    (Solid::from_tree("phi".into(), b.build(), m).unwrap(), tiles)
}

const VOXEL: f64 = 0.1;
const OFFSET: [f64; 3] = [1.0, -2.0, 0.5];

fn world(p: DVec3) -> DVec3 {
    p * VOXEL + DVec3::from_array(OFFSET)
}

/// Sphere of radius `r` voxels centred at index point `c`.
fn sphere(c: DVec3, r: f64) -> Solid {
    let reach = r + BAND + 2.0;
    let lo = (c - reach).floor().as_ivec3().to_array();
    let hi = (c + reach).ceil().as_ivec3().to_array();
    let (solid, tiles) = level_set(|p| (p - c).length() - r, lo, hi, VOXEL, OFFSET);
    assert!(tiles > 0, "the interior is filled with tiles");
    solid
}

/// Entry distance of the ray `o + t u` (unit `u`) into the sphere (world centre `c`, radius
/// `r`), if the line meets it ahead.
fn sphere_entry(o: DVec3, u: DVec3, c: DVec3, r: f64) -> Option<f64> {
    let b = u.dot(c - o);
    let disc = b * b - ((o - c).length_squared() - r * r);
    (disc >= 0.0).then(|| b - disc.sqrt())
}

/// A random unit vector.
fn unit(rng: &mut impl Rng) -> DVec3 {
    loop {
        let v = DVec3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        );
        let l = v.length();
        if l > 0.1 && l < 1.0 {
            return v / l;
        }
    }
}

/// A unit vector perpendicular to `u`.
fn perpendicular(u: DVec3, rng: &mut impl Rng) -> DVec3 {
    loop {
        let v = unit(rng);
        let p = v - u * v.dot(u);
        if p.length() > 0.1 {
            return p.normalize();
        }
    }
}

#[test]
fn sphere_hits_match_the_analytic_entry() {
    let c = DVec3::new(3.37, -2.21, 5.45);
    let r = 12.3;
    let solid = sphere(c, r);
    let (cw, rw) = (world(c), r * VOXEL);
    let mut rng = rand::rngs::StdRng::seed_from_u64(20240611);
    let mut worst = 0.0f64;
    for _ in 0..2000 {
        // From 1.5 to 4 radii away, aimed at a point of the sphere's disc seen from there
        // (impact parameter up to 0.95 r).
        let o = cw + unit(&mut rng) * rw * rng.gen_range(1.5..4.0);
        let u0 = (cw - o).normalize();
        let aim = cw + perpendicular(u0, &mut rng) * rw * rng.gen_range(0.0..0.95);
        let u = (aim - o).normalize();
        let ray = Ray::new(o, u, 0.0, f64::INFINITY).unwrap();
        let want = sphere_entry(o, u, cw, rw).unwrap();
        let got = solid.first_hit(&ray).expect("the ray hits the sphere");
        worst = worst.max((got - want).abs() / VOXEL);
    }
    eprintln!("sphere: max |first_hit - analytic entry| = {worst:.4} voxel");
    // The trilinear zero set of a sampled sphere SDF deviates from the sphere by a small
    // fraction of a voxel (the SDF's curvature 1/r is what trilinear interpolation misses),
    // stretched along the ray by up to 1 / cos = 3.2 at impact parameters up to 0.95 r.
    // Measured 0.0486 voxel over these 2000 rays (r = 12.3 voxels).
    assert!(worst < 0.06, "{worst}");
}

#[test]
fn sphere_misses_inside_starts_and_rays_past_it() {
    let c = DVec3::new(-4.6, 3.2, 11.3);
    let r = 13.0;
    let solid = sphere(c, r);
    let (cw, rw) = (world(c), r * VOXEL);
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    for _ in 0..1000 {
        // Impact parameter (distance of the line from the centre) from r + 1 voxel to 2 r:
        // a miss.
        let u = unit(&mut rng);
        let b = rw + VOXEL * rng.gen_range(1.0..(r + 1.0));
        let closest = cw + perpendicular(u, &mut rng) * b;
        let o = closest - u * rw * rng.gen_range(1.5..4.0);
        let ray = Ray::new(o, u, 0.0, f64::INFINITY).unwrap();
        assert_eq!(solid.first_hit(&ray), None, "impact {}", b / VOXEL);
    }
    for _ in 0..200 {
        let u = unit(&mut rng);
        // Starting inside (the origin anywhere inside, or outside with t_min inside).
        let o = cw + unit(&mut rng) * rw * rng.gen_range(0.0..0.9);
        let ray = Ray::new(o, u, 0.0, 1e3).unwrap();
        assert_eq!(solid.first_hit(&ray), Some(0.0));
        // From two radii before the centre: inside for t in (r, 3 r).
        let far = cw - u * rw * 2.0;
        let t_min = rw * rng.gen_range(1.1..2.9);
        let ray = Ray::new(far, u, t_min, f64::INFINITY).unwrap();
        assert_eq!(solid.first_hit(&ray), Some(t_min));
        // From t_min beyond the sphere: nothing ahead.
        let t_min = rw * rng.gen_range(3.1..5.0);
        let ray = Ray::new(far, u, t_min, f64::INFINITY).unwrap();
        assert_eq!(solid.first_hit(&ray), None);
        // Stopping before it: nothing either.
        let ray = Ray::new(far, u, 0.0, rw * 0.9).unwrap();
        assert_eq!(solid.first_hit(&ray), None);
    }
}

/// Exact signed distance to the box of centre `c`, half extents `h`.
fn box_sdf(p: DVec3, c: DVec3, h: DVec3) -> f64 {
    let q = (p - c).abs() - h;
    q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
}

#[test]
fn box_faces_are_hit_exactly_and_grazing_rays_behave() {
    let c = DVec3::new(1.3, -0.45, 2.7);
    let h = DVec3::new(10.25, 10.6, 8.35);
    let reach = h + BAND + 2.0;
    let lo = (c - reach).floor().as_ivec3().to_array();
    let hi = (c + reach).ceil().as_ivec3().to_array();
    let (solid, tiles) = level_set(|p| box_sdf(p, c, h), lo, hi, VOXEL, OFFSET);
    assert!(tiles > 0);
    let mut rng = rand::rngs::StdRng::seed_from_u64(99);
    let mut worst = 0.0f64;
    for _ in 0..2000 {
        // A point of a face at least 2 voxels from its edges, and a ray into the box through
        // it: the box is convex, so that point is the entry.
        let a = rng.gen_range(0..3);
        let side = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        let mut target = c;
        target[a] += side * h[a];
        for b in (0..3).filter(|&b| b != a) {
            target[b] += rng.gen_range(-(h[b] - 2.0)..(h[b] - 2.0));
        }
        let mut out = unit(&mut rng);
        out[a] = side * out[a].abs().max(0.3);
        let out = out.normalize();
        let dist = rng.gen_range(5.0..40.0);
        let o = world(target + out * dist);
        let u = -out;
        let ray = Ray::new(o, u, 0.0, f64::INFINITY).unwrap();
        let got = solid.first_hit(&ray).expect("the ray enters the box");
        worst = worst.max((got / VOXEL - dist).abs());
    }
    eprintln!("box faces: max |first_hit - face distance| = {worst:.3e} voxel");
    // Near a face (away from edges) the SDF is linear, so its trilinear interpolation is exact
    // and only the bisection bracket (1e-6 voxel of index-space length) and f32 values remain.
    // Measured 9.8e-7 voxel.
    assert!(worst < 2e-6, "{worst}");

    // Grazing: along y, a quarter voxel inside the +x face (enters through the -y face, next to
    // the edge where the outside SDF is curved) and a quarter voxel outside it (a miss).
    let start = |dx: f64| c + DVec3::new(h.x + dx, -h.y - 20.0, 0.0);
    let ray = Ray::new(world(start(-0.25)), DVec3::Y, 0.0, f64::INFINITY).unwrap();
    let got = solid
        .first_hit(&ray)
        .expect("a quarter voxel inside the face")
        / VOXEL;
    eprintln!(
        "box grazing inside: |t - 20| = {:.3e} voxel",
        (got - 20.0).abs()
    );
    // Near the edge the sampled SDF is `max(qx, qy)` inside (a kink) and a distance to the
    // edge outside (curved): neither is trilinear, so the interpolated edge is rounded by a
    // fraction of a voxel. Measured 0.336 voxel here.
    assert!((got - 20.0).abs() < 0.5, "{got}");
    let ray = Ray::new(world(start(0.25)), DVec3::Y, 0.0, f64::INFINITY).unwrap();
    assert_eq!(solid.first_hit(&ray), None);

    // Shallow entries through the middle of the +z face (1/50 of a radian and less): the field
    // is linear there, so the hit stays exact even though every voxel of error along the normal
    // would be 50 voxels along the ray.
    let mut worst = 0.0f64;
    for k in 1..=20 {
        let slope = 0.02 / f64::from(k);
        let u = DVec3::new(1.0, 0.3, -slope).normalize();
        let target = c + DVec3::new(0.0, 0.0, h.z);
        let dist = 5.0 / u.z.abs();
        let o = world(target - u * dist);
        let ray = Ray::new(o, u, 0.0, f64::INFINITY).unwrap();
        let got = solid.first_hit(&ray).expect("a shallow entry") / VOXEL;
        worst = worst.max((got - dist).abs() * u.z.abs());
    }
    eprintln!("box shallow entries: max error along the normal {worst:.3e} voxel");
    assert!(worst < 2e-6, "{worst}");
}

#[test]
fn a_field_linear_along_the_ray_is_crossed_exactly() {
    // phi = 10.3 - x (inside for x > 10.3), unit voxels at the origin: a ray along +x from
    // x = 0 enters at x = 10.3, and an oblique one where its x reaches 10.3.
    let mut b = TreeBuilder::new(BAND as f32);
    let phi = |i: i32| (10.3 - f64::from(i)).clamp(-BAND, BAND) as f32;
    for i in -8..40 {
        for j in -8..16 {
            for k in -8..16 {
                b.set([i, j, k], phi(i));
            }
        }
    }
    let id = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ];
    let solid = Solid::from_tree("plane".into(), b.build(), id).unwrap();
    // The zero of the field umbra holds (f32 voxel values) in the cell [10, 11].
    let (v10, v11) = (f64::from(phi(10)), f64::from(phi(11)));
    let exact = 10.0 + v10 / (v10 - v11);
    let ray = Ray::new([0.0, 0.3, 0.7], [1.0, 0.0, 0.0], 0.0, 100.0).unwrap();
    let t = solid.first_hit(&ray).unwrap();
    eprintln!(
        "plane: |t - zero| = {:.3e}, |t - 10.3| = {:.3e} voxel",
        (t - exact).abs(),
        (t - 10.3).abs()
    );
    assert!((t - exact).abs() < 1e-6 && (t - 10.3).abs() < 1e-6, "{t}");
    assert!(
        t >= exact - 1e-12,
        "the hit is on the inside end of the bracket"
    );
    let u = DVec3::new(0.8, 0.36, 0.48);
    let ray = Ray::new([0.0, 0.2, 0.1], u, 0.0, 100.0).unwrap();
    let t = solid.first_hit(&ray).unwrap();
    // Index-space length along the ray is t (unit voxels): 1e-6 voxel in t.
    let want = exact / u.normalize().x;
    assert!((t - want).abs() < 1e-6, "{t} vs {want}");
}

#[test]
fn corpus_sphere_is_hit_at_its_radius() {
    let Some(dir) = common::corpus_dir() else {
        return;
    };
    // manifest.json: pyopenvdb.createLevelSetSphere(radius=1.0, center=(0.1,-0.2,0.3),
    // voxelSize=0.02, halfWidth=3.0).
    let solid = Solid::load(dir.join("gen/sphere_levelset.vdb"), "ls_sphere").unwrap();
    let (c, r, voxel) = (DVec3::new(0.1, -0.2, 0.3), 1.0, 0.02);
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let mut worst = 0.0f64;
    for _ in 0..200 {
        let o = c + unit(&mut rng) * rng.gen_range(1.5..5.0);
        let ray = Ray::new(o, c - o, 0.0, f64::INFINITY).unwrap();
        let got = solid
            .first_hit(&ray)
            .expect("a ray through the centre hits");
        worst = worst.max((got - ((o - c).length() - r)).abs() / voxel);
        // Starting at the centre: inside.
        let inside = Ray::new(c, o - c, 0.0, 10.0).unwrap();
        assert_eq!(solid.first_hit(&inside), Some(0.0));
        // A line passing 1.2 radii from the centre: a miss.
        let u = (c - o).normalize();
        let closest = c + perpendicular(u, &mut rng) * 1.2 * r;
        let miss = Ray::new(closest - u * 3.0, u, 0.0, f64::INFINITY).unwrap();
        assert_eq!(solid.first_hit(&miss), None);
    }
    eprintln!("corpus sphere: max |first_hit - (|o - c| - r)| = {worst:.4} voxel");
    // Normal incidence on a 50-voxel sphere: measured 0.005 voxel (one voxel is the bound the
    // corpus's own sampling guarantees; this is much tighter).
    assert!(worst < 0.05, "{worst}");
}

#[test]
fn a_translation_moves_the_hit() {
    let c = DVec3::new(3.5, 3.5, 3.5);
    let r = 14.0;
    let solid = sphere(c, r);
    let shift = DVec3::new(0.7, -1.3, 2.2);
    let x = Xform::new([
        [1.0, 0.0, 0.0, shift.x],
        [0.0, 1.0, 0.0, shift.y],
        [0.0, 0.0, 1.0, shift.z],
        [0.0, 0.0, 0.0, 1.0],
    ])
    .unwrap();
    let moved = solid.clone().with_xform(&x).unwrap();
    assert_eq!(moved.xform(), Some(x));
    assert_eq!(solid.xform(), None);
    assert_eq!(moved.name(), "phi");
    let corners = (solid.box_corners().unwrap(), moved.box_corners().unwrap());
    for (a, b) in corners.0.iter().zip(&corners.1) {
        assert!((*b - *a - shift).length() < 1e-12);
    }
    let mut rng = rand::rngs::StdRng::seed_from_u64(11);
    let (cw, rw) = (world(c), r * VOXEL);
    let mut counts = [0; 3];
    for _ in 0..300 {
        let o = cw + unit(&mut rng) * rw * rng.gen_range(1.5..3.0);
        let aim = cw + unit(&mut rng) * rw * 0.5;
        let u = aim - o;
        let before = solid.first_hit(&Ray::new(o, u, 0.0, 1e3).unwrap()).unwrap();
        // The same ray moved with the solid hits at the same distance...
        let after = moved
            .first_hit(&Ray::new(o + shift, u, 0.0, 1e3).unwrap())
            .unwrap();
        assert!((after - before).abs() < 1e-9, "{before} vs {after}");
        // ...and the unmoved ray now hits elsewhere, at the analytic entry of the moved sphere
        // (or not at all).
        let ray = Ray::new(o, u, 0.0, 1e3).unwrap();
        let cm = cw + shift;
        let want = if (o - cm).length() < rw {
            Some(0.0)
        } else {
            sphere_entry(o, ray.direction(), cm, rw).filter(|&t| t >= 0.0)
        };
        match (moved.first_hit(&ray), want) {
            (Some(t), Some(w)) => {
                assert!((t - w).abs() < 0.5 * VOXEL, "{t} vs {w}");
                counts[usize::from(w > 0.0)] += 1;
            }
            (None, None) => counts[2] += 1,
            // Within a voxel of grazing, or of starting on the surface, either answer is right.
            (got, want) => {
                let b = (cm - o).cross(ray.direction()).length();
                let on = ((o - cm).length() - rw).abs();
                assert!((b - rw).abs() < VOXEL || on < VOXEL, "{got:?} vs {want:?}");
            }
        }
    }
    // Starting inside, hitting ahead, missing: each case is exercised.
    assert!(counts.iter().all(|&n| n >= 5), "{counts:?}");
}

#[test]
fn grids_that_cannot_be_solids_are_refused() {
    // Everything inside: a negative background is refused, naming the grid.
    let mut b = TreeBuilder::new(-1.0);
    b.set([0, 0, 0], 2.0);
    let id = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ];
    match Solid::from_tree("inv".into(), b.build(), id) {
        Err(umbra::Error::InvalidArgument { name, reason }) => {
            assert_eq!(name, "background");
            assert!(
                reason.contains("'inv'") && reason.contains("inside"),
                "{reason}"
            );
        }
        other => panic!("{other:?}"),
    }
    let ray = Ray::new([50.0, 0.0, 0.0], [1.0, 0.0, 0.0], 2.5, 9.0).unwrap();
    // A singular map is an error, not a panic.
    let mut m = id;
    m[2][2] = 0.0;
    assert!(Solid::from_tree("flat".into(), TreeBuilder::new(1.0).build(), m).is_err());
    // An empty grid has no box and no hit.
    let empty = Solid::from_tree("empty".into(), TreeBuilder::new(1.0).build(), id).unwrap();
    assert!(empty.box_corners().is_err());
    assert_eq!(empty.first_hit(&ray), None);
}

#[test]
fn corpus_grids_that_cannot_be_solids_are_refused() {
    let Some(dir) = common::corpus_dir() else {
        return;
    };
    let unsupported = |file: &str, grid: &str| match Solid::load(dir.join(file), grid) {
        Err(umbra::Error::Unsupported { path, what }) => {
            assert!(path.ends_with(file), "{}", path.display());
            what
        }
        other => panic!("{file} {grid}: expected Unsupported, got {other:?}"),
    };
    let what = unsupported("gen/multigrid_smoke.vdb", "velocity");
    assert!(
        what.contains("vec3s") && what.contains("velocity"),
        "{what}"
    );
    let what = unsupported("gen/int32_flags.vdb", "flags");
    assert!(what.contains("flags"), "{what}");
    let what = unsupported("gen/xform_frustum.vdb", "density");
    assert!(
        what.contains("Frustum") && what.contains("density"),
        "{what}"
    );
    // Any class is accepted (the caller vouches for a signed distance): a fog volume's
    // non-negative values hold no `phi < 0`, so nothing is ever hit.
    let fog = Solid::load(dir.join("gen/sphere_fog.vdb"), "density").unwrap();
    let ray = Ray::new([-5.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0, f64::INFINITY).unwrap();
    assert_eq!(fog.first_hit(&ray), None);
}

/// A level set whose background is 0 (a Blender liquid's `phi`): outside its band the field
/// reads as "on the surface". Rays that only touch 0 (where band voxels meet the background,
/// often at the ray's very end, on the clip box) are not hits: every ray that stays two voxels
/// away from the one negative voxel misses, and rays through it hit.
#[test]
fn touching_zero_is_not_a_hit() {
    let mut b = TreeBuilder::new(0.0);
    for i in 0..16 {
        for j in 0..16 {
            for k in 0..16 {
                b.set([i, j, k], 2.5);
            }
        }
    }
    b.set([12, 12, 12], -1.0);
    let id = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ];
    let s = Solid::from_tree("phi0".into(), b.build(), id).unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(11);
    let neg = DVec3::splat(12.0);
    let (mut misses, mut hits) = (0, 0);
    for _ in 0..20000 {
        // From a point on a sphere around the block to a point on its faces or edges, often
        // exactly on the planes where the band meets the background (15 and 16).
        let d = unit(&mut rng);
        let from = DVec3::splat(7.5) - 30.0 * d;
        let pick = |r: &mut rand::rngs::StdRng| match r.gen_range(0..4) {
            0 => 15.0,
            1 => 16.0,
            2 => -1.0,
            _ => r.gen_range(-1.0..16.0),
        };
        let to = DVec3::new(pick(&mut rng), pick(&mut rng), pick(&mut rng));
        let Ok(ray) = Ray::between(from.to_array(), to.to_array()) else {
            continue;
        };
        // Distance of the negative voxel from the segment.
        let u = ray.direction();
        let o = ray.origin();
        let t = (neg - o).dot(u).clamp(0.0, ray.t_max());
        let far = (o + t * u - neg).length() > 2.0;
        match s.first_hit(&ray) {
            Some(t) if far => panic!("{ray:?}: a hit at {t} where phi only touches 0"),
            Some(_) => hits += 1,
            None if far => misses += 1,
            None => {}
        }
    }
    assert!(misses > 10000 && hits > 0, "{misses} misses, {hits} hits");
}
