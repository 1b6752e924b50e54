//! Partial loads (issue 18): a grid opened lazily decodes only the leaves a job's rays touch,
//! and every answer on those rays equals an eager load's bit for bit, for every estimator,
//! interpolation and granularity; what it did not read can never become a number; corrupt leaf
//! data is found by the load that touches it, naming the file and the byte offset; a full
//! parallel decode does not depend on the thread count.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[allow(unused_imports)]
use crate::common;

use common::data;
use rand::{Rng, SeedableRng};
use std::path::PathBuf;
use umbra::estimate::{Estimator, Options};
use umbra::input::SourceOptions;
use umbra::internals::traverse::Granularity;
use umbra::scene;
use umbra::{Interp, Ray, Volume};

fn corpus(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus")
        .join(name)
}

/// `n` random segments (seeded) between points in the volume's world box grown by a fifth,
/// plus one ray from inside to infinity.
fn rays(vol: &Volume, n: usize, seed: u64) -> Vec<Ray> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let (lo, hi) = vol.box_index().unwrap();
    let pad = (hi - lo) * 0.2;
    let (lo, hi) = (lo - pad, hi + pad);
    let mut point = || {
        let t = glam::DVec3::new(rng.gen(), rng.gen(), rng.gen());
        vol.to_world(lo + (hi - lo) * t).to_array()
    };
    let mut out: Vec<Ray> = (0..n)
        .filter_map(|_| Ray::between(point(), point()).ok())
        .collect();
    let c = vol.to_world((lo + hi) * 0.5).to_array();
    out.push(Ray::new(c, [0.3, -1.0, 0.2], 0.0, f64::INFINITY).unwrap());
    out
}

fn opts(grid: &str) -> SourceOptions {
    SourceOptions {
        grid: grid.into(),
        ..SourceOptions::default()
    }
}

/// Every answer of `est` on `rays` from a partial load equals the eager load's, bit for bit.
fn same_answers(
    eager: &scene::Scene,
    lazy: &scene::Scene,
    rays: &[Ray],
    est: &Estimator,
    o: &Options,
    what: &str,
) {
    for (i, r) in rays.iter().enumerate() {
        let a = scene::estimate(eager, r, i as u64, est, o);
        let b = scene::estimate(lazy, r, i as u64, est, o);
        match (a, b) {
            (Ok(a), Ok(b)) => {
                let bits = |e: &scene::SceneEstimate| {
                    (
                        e.value.map(f64::to_bits),
                        e.std_err.map(f64::to_bits),
                        e.tau.map(|t| t.map(f64::to_bits)),
                        e.lookups,
                        e.segments,
                    )
                };
                assert_eq!(bits(&a), bits(&b), "{what}, ray {i}: {a:?} vs {b:?}");
            }
            (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{what}, ray {i}"),
            (a, b) => panic!("{what}, ray {i}: eager {a:?}, lazy {b:?}"),
        }
    }
}

#[test]
fn partial_loads_answer_like_eager_loads_bit_for_bit() {
    let files = [
        (data("cloud.vdb"), "density"),
        (data("cloud_half.vdb"), "density"),
        (data("box_tiles.vdb"), "density"),
        (data("bg_multi.vdb"), "density"),
        (corpus("gen/cloud_fbm.vdb"), "density"),
        (corpus("gen/negative_coords.vdb"), "density"),
        (corpus("gen/extreme_nan_inf.vdb"), "density"),
        (corpus("gen/fog_nonzero_background.vdb"), "density"),
        (corpus("gen/puff_none.vdb"), "density"),
        (corpus("gen/puff_blosc_nomask.vdb"), "density"),
        (corpus("real/blender_smoke_fluid_data_0050.vdb"), "density"),
    ];
    let stochastic = [
        "ratio",
        "track-length",
        "residual-ratio",
        "unbiased-raymarch",
        "riemann",
    ];
    let mut partial_somewhere = false;
    for (path, grid) in &files {
        let eager = umbra::input::Source::new(path, opts(grid).clone())
            .load()
            .unwrap();
        let vol = eager.fogs()[0].volume();
        let all = vol.tree().leaves().len();
        for (k, (interp, gran)) in [
            (Interp::Trilinear, Granularity::Leaf),
            (Interp::Nearest, Granularity::Leaf),
            (Interp::Trilinear, Granularity::Lower),
            (Interp::Trilinear, Granularity::Upper),
        ]
        .into_iter()
        .enumerate()
        {
            let r = rays(vol, 24, 7 + k as u64);
            let source = umbra::input::Source::new(
                path,
                SourceOptions {
                    interp,
                    ..opts(grid)
                },
            );
            let (lazy, got) = source.load_for_rays(gran, 0, |_| r.clone()).unwrap();
            assert_eq!(got.len(), r.len());
            let loaded = lazy.fogs()[0].volume().tree().loaded_leaf_count();
            assert!(loaded <= all);
            // One ray reads a small part of a many-leaf grid.
            if k == 0 && all > 100 {
                let one = &r[..1];
                let (single, _) = source.load_for_rays(gran, 0, |_| one.to_vec()).unwrap();
                let n = single.fogs()[0].volume().tree().loaded_leaf_count();
                assert!(
                    n < all / 2,
                    "{}: one ray loaded {n} of {all} leaves",
                    path.display()
                );
                partial_somewhere = true;
                same_answers(
                    &eager,
                    &single,
                    one,
                    &Estimator::from_name("regular").unwrap(),
                    &Options {
                        interp,
                        granularity: gran,
                        ..Options::default()
                    },
                    "one ray",
                );
            }
            let what = format!("{} {interp:?} {gran:?}", path.display());
            let o = Options {
                interp,
                granularity: gran,
                samples: 16,
                seed: 3,
                ..Options::default()
            };
            same_answers(
                &eager,
                &lazy,
                &r,
                &Estimator::from_name("regular").unwrap(),
                &o,
                &what,
            );
            for name in stochastic {
                let est = Estimator::from_name(name).unwrap();
                same_answers(&eager, &lazy, &r, &est, &o, &format!("{what} {name}"));
            }
        }
    }
    assert!(partial_somewhere);
}

#[test]
fn rgb_and_xform_partial_loads_equal_eager_ones() {
    let o = SourceOptions {
        sigma_t: Some([0.5, 1.0, 2.0]),
        xform: Some(vec![
            0.0, -2.0, 0.0, 1.0, 2.0, 0.0, 0.0, -0.5, 0.0, 0.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0,
        ]),
        ..SourceOptions::default()
    };
    let path = data("cloud.vdb");
    let eager = umbra::input::Source::new(&path, o.clone()).load().unwrap();
    let r = rays(eager.fogs()[0].volume(), 30, 11);
    let (lazy, _) = umbra::input::Source::new(&path, o.clone())
        .load_for_rays(Granularity::Leaf, 0, |_| r.clone())
        .unwrap();
    let opts = Options {
        samples: 8,
        ..Options::default()
    };
    for name in ["regular", "ratio", "next-flight"] {
        let est = Estimator::from_name(name).unwrap();
        same_answers(&eager, &lazy, &r, &est, &opts, name);
    }
}

#[test]
fn what_a_partial_load_did_not_read_never_becomes_a_number() {
    let path = data("cloud.vdb");
    let archive = umbra::internals::vdb::open(&path).unwrap();
    let lazy = archive
        .open_lazy(archive.find_grid("density").unwrap())
        .unwrap();
    assert!(lazy.leaf_count() > 100);
    let shell = Volume::new(lazy.shell().clone(), 1.0, &path).unwrap();
    let eager = Volume::load(&path, "density", 1.0).unwrap();
    let through = Ray::between([-2.0, 0.5, 0.0], [2.0, 0.5, 0.0]).unwrap();
    assert!(
        umbra::regular::optical_depth(&eager, &through, Interp::Trilinear)
            .unwrap()
            .tau
            > 0.1
    );
    // The shell: values unread, bounds never computed.
    let o = Options {
        samples: 4,
        ..Options::default()
    };
    for name in ["regular", "ratio", "track-length"] {
        let est = Estimator::from_name(name).unwrap();
        let e = umbra::estimate::estimate(&shell, &through, 0, &est, &o);
        assert!(e.is_err(), "{name} on the shell gave {e:?}");
    }
    // A partial load of other leaves than the ray's.
    let far = Ray::between([-2.0, 1.9, 1.9], [2.0, 1.9, 1.9]).unwrap();
    let leaves = umbra::internals::demand::leaves_touched(
        &shell,
        &[far],
        Interp::Trilinear,
        Granularity::Leaf,
    );
    let part = Volume::new(lazy.load(&leaves).unwrap(), 1.0, &path).unwrap();
    assert!(part.tree().loaded_leaf_count() < lazy.leaf_count());
    for name in ["regular", "ratio", "track-length", "riemann"] {
        let est = Estimator::from_name(name).unwrap();
        let e = umbra::estimate::estimate(&part, &through, 0, &est, &o);
        assert!(
            matches!(e, Err(umbra::Error::NotANumber { .. })),
            "{name} through unread leaves gave {e:?}"
        );
    }
    assert!(umbra::regular::optical_depth(&part, &through, Interp::Nearest).is_err());
    // The grid-wide majorant needs every leaf.
    let global = Options {
        global_majorant: true,
        ..o
    };
    let ratio = Estimator::from_name("ratio").unwrap();
    assert!(umbra::estimate::estimate(&part, &far, 0, &ratio, &global).is_err());
    assert!(umbra::estimate::estimate(&eager, &far, 0, &ratio, &global).is_ok());
    // Index checks.
    assert!(matches!(
        lazy.load(&[u32::MAX]),
        Err(umbra::Error::InvalidArgument { .. })
    ));
}

/// A copy of `src` whose leaf `leaf` has a blosc chunk that claims another size.
fn corrupt_leaf(src: &std::path::Path, dir: &std::path::Path, leaf: u32) -> (PathBuf, u64) {
    let archive = umbra::internals::vdb::open(src).unwrap();
    let lazy = archive
        .open_lazy(archive.find_grid("density").unwrap())
        .unwrap();
    let range = lazy.buffer_range(leaf).unwrap();
    let mut bytes = std::fs::read(src).unwrap();
    let at = range.start as usize;
    let meta = bytes[at + 64];
    let skip = match meta {
        2 => 4,
        3 => 64,
        4 => 4 + 64,
        5 => 8 + 64,
        _ => 0,
    };
    let chunk = at + 64 + 1 + skip + 8;
    // The blosc header's uncompressed size (bytes 4..8).
    bytes[chunk + 4..chunk + 8].copy_from_slice(&7u32.to_le_bytes());
    let out = dir.join("corrupt.vdb");
    std::fs::write(&out, bytes).unwrap();
    (out, range.start)
}

#[test]
fn corrupt_leaf_data_is_found_by_the_load_that_touches_it() {
    let dir = tempfile::tempdir().unwrap();
    let src = data("cloud.vdb");
    let (path, offset) = corrupt_leaf(&src, dir.path(), 5);
    let archive = umbra::internals::vdb::open(&path).unwrap();
    let gd = archive.find_grid("density").unwrap();
    // Opening reads no values; an eager load meets the corrupt leaf.
    let lazy = archive.open_lazy(gd).unwrap();
    let e = archive.load(gd).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, umbra::Error::Invalid { .. }), "{e:?}");
    assert!(msg.contains(&path.display().to_string()), "{msg}");
    assert!(msg.contains(&format!("byte offset {offset}")), "{msg}");
    // Leaves other than the corrupt one load; the corrupt one is named.
    let others: Vec<u32> = (0..lazy.leaf_count() as u32).filter(|&l| l != 5).collect();
    assert!(lazy.load(&others).is_ok());
    let e = lazy.load(&[5]).unwrap_err();
    assert!(
        e.to_string().contains(&format!("byte offset {offset}")),
        "{e}"
    );
    // Through the CLI: a query whose ray touches the leaf fails (exit 1, one line naming the
    // file and the offset); one that does not succeeds.
    let shell = Volume::new(lazy.shell().clone(), 1.0, &path).unwrap();
    let origin = lazy.shell().tree.leaves()[5]
        .origin
        .map(|c| f64::from(c) + 4.0);
    let p = shell.to_world(glam::DVec3::from_array(origin)).to_array();
    let at = format!("{},{},{}", p[0], p[1], p[2]);
    let o = assert_cmd::Command::cargo_bin("umbra")
        .unwrap()
        .args([
            "query",
            path.to_str().unwrap(),
            "--at",
            &at,
            "--light-dir",
            "0,-1,0",
            "--load",
            "lazy",
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.starts_with("umbra: error: "), "{err}");
    assert!(
        err.contains("corrupt.vdb") && err.contains(&format!("byte offset {offset}")),
        "{err}"
    );
    let o = assert_cmd::Command::cargo_bin("umbra")
        .unwrap()
        .args([
            "query",
            path.to_str().unwrap(),
            "--from",
            "-9,-9,-9",
            "--to",
            "-9,-9,9",
            "--load",
            "lazy",
        ])
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn a_query_decodes_what_it_needs_and_answers_like_eager() {
    let path = data("cloud.vdb");
    let run = |extra: &[&str]| {
        let o = assert_cmd::Command::cargo_bin("umbra")
            .unwrap()
            .args(["query", path.to_str().unwrap(), "--at", "0.1,0.2,0.3"])
            .args([
                "--light-dir",
                "0.2,-1,0.1",
                "--estimator",
                "ratio",
                "--samples",
                "64",
            ])
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8(o.stdout).unwrap()
    };
    assert_eq!(run(&["--load", "lazy"]), run(&["--load", "eager"]));
    assert_eq!(run(&[]), run(&["--load", "eager"]));
    // JSON, without the timing.
    let json = |extra: &[&str]| {
        let mut v: serde_json::Value = serde_json::from_str(&run(extra)).unwrap();
        v.as_object_mut().unwrap().remove("seconds");
        v
    };
    assert_eq!(
        json(&["--json", "--load", "lazy"]),
        json(&["--json", "--load", "eager"])
    );
    // Exact rows go in batches on the kernel, which copies every + neighbour of a leaf: the
    // leaves a lazy load decodes for them give the eager answers bit for bit.
    let rows: String = (0..200)
        .map(|i| {
            let a = f64::from(i) * 0.731;
            format!(
                "{},{},{},{},{},{}\n",
                2.5 * a.cos(),
                -1.0 + f64::from(i % 17) * 0.12,
                2.5 * a.sin(),
                -2.0 * (a + 0.5).cos(),
                1.2 - f64::from(i % 13) * 0.15,
                -2.0 * (a + 0.5).sin()
            )
        })
        .collect();
    let exact = |load: &str| {
        let o = assert_cmd::Command::cargo_bin("umbra")
            .unwrap()
            .args([
                "query",
                path.to_str().unwrap(),
                "--rays",
                "-",
                "--json",
                "--load",
                load,
            ])
            .write_stdin(rows.clone())
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let taus: Vec<f64> = String::from_utf8(o.stdout)
            .unwrap()
            .lines()
            .map(|l| {
                serde_json::from_str::<serde_json::Value>(l).unwrap()["tau"]
                    .as_f64()
                    .unwrap()
            })
            .collect();
        taus
    };
    let lazy = exact("lazy");
    assert_eq!(lazy.len(), 200);
    assert!(
        lazy.iter().filter(|&&t| t > 0.05).count() > 50,
        "rays cross the cloud"
    );
    assert_eq!(lazy, exact("eager"));
}

#[test]
fn a_full_parallel_decode_does_not_depend_on_the_thread_count() {
    let path = corpus("real/blender_smoke_fluid_data_0050.vdb");
    let load = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| Volume::load(&path, "density", 1.0).unwrap())
    };
    let (a, b) = (load(1), load(2));
    let (ta, tb) = (a.tree(), b.tree());
    assert!(ta.is_complete() && tb.is_complete());
    assert_eq!(ta.leaves().len(), tb.leaves().len());
    for l in 0..ta.leaves().len() as u32 {
        let (x, y) = (ta.leaf_values(l), tb.leaf_values(l));
        assert!(x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()));
        let (la, lb) = (&ta.leaves()[l as usize], &tb.leaves()[l as usize]);
        assert_eq!((la.bounds, la.halo), (lb.bounds, lb.halo));
    }
    assert_eq!(ta.stats(), tb.stats());
}

#[test]
fn streamed_info_equals_the_report_of_a_full_load() {
    let mut files: Vec<PathBuf> = ["data", "../shared/corpus/gen", "../shared/corpus/real"]
        .iter()
        .flat_map(|d| {
            std::fs::read_dir(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(d))
                .into_iter()
                .flatten()
                .flatten()
                .map(|e| e.path())
        })
        .filter(|p| p.extension().is_some_and(|x| x == "vdb"))
        .collect();
    files.sort();
    let mut grids = 0;
    for path in files {
        let Ok(archive) = umbra::internals::vdb::open(&path) else {
            continue;
        };
        for gd in &archive.grids {
            let Ok(grid) = archive.load(gd) else {
                assert!(archive.open_lazy(gd).and_then(|l| l.stats()).is_err());
                continue;
            };
            let eager = umbra::info::GridInfo::from_grid(&grid, &gd.tree_type);
            let lazy = archive.open_lazy(gd).unwrap();
            let streamed = umbra::info::GridInfo::from_lazy(&lazy, &gd.tree_type).unwrap();
            let json = |g: &umbra::info::GridInfo| {
                let mut v = serde_json::to_value(g).unwrap();
                v.as_object_mut().unwrap().remove("memory_bytes");
                v
            };
            let what = format!("{} {}", path.display(), gd.display_name);
            assert_eq!(json(&eager), json(&streamed), "{what}");
            let (a, b) = (eager.memory_bytes.unwrap(), streamed.memory_bytes.unwrap());
            assert!(b <= a && a - b <= a / 100 + 4096, "{what}: {a} vs {b}");
            grids += 1;
        }
    }
    assert!(grids >= 30, "{grids}");
}

/// A bake job of `path` with an exact trilinear map, 3 slices.
fn bake_job(path: &std::path::Path, out: PathBuf, max_memory: Option<u64>) -> umbra::bake::BakeJob {
    use umbra::bake::{BakeJob, BakeSettings, Depths, Projection, Resolution, View};
    let mut settings =
        BakeSettings::new(Estimator::from_name("regular").unwrap(), Options::default());
    settings.depths = Depths::Slices(3);
    BakeJob {
        source: umbra::input::Source::new(
            path.to_path_buf(),
            umbra::input::SourceOptions {
                grid: "density".into(),
                density_scale: 1.0,
                ..umbra::input::SourceOptions::default()
            },
        ),
        view: View {
            projection: Projection::Ortho,
            light_dir: Some([0.3, -1.0, 0.2]),
            light_pos: None,
            fov_deg: None,
            res: Some(Resolution::Exact(300, 200)),
            up: None,
            frame_box: None,
        },
        camera: None,
        settings,
        output: out,
        preview: None,
        overwrite: true,
        max_memory,
        layout: umbra::bake::ExrLayout::default(),
        product: umbra::bake::Product::Map,
        key: None,
    }
}

/// The least budget `job`'s plan accepts, read from its refusal of 1 MiB (which names it and
/// the option `max-memory`).
pub(crate) fn least_budget(job: &umbra::bake::BakeJob) -> u64 {
    let mut j = job.clone();
    j.max_memory = Some(1 << 20);
    match j.plan_bounded() {
        Err(umbra::Error::InvalidArgument { name, reason }) => {
            assert_eq!(name, "max-memory");
            let at_least = reason.split("at least ").nth(1).unwrap();
            let mib: f64 = at_least.split(' ').next().unwrap().parse().unwrap();
            (mib * f64::from(1 << 20)) as u64
        }
        other => panic!("{other:?}"),
    }
}

/// A cache of 3 x 3 x 3 copies of the sample cloud (`tools/make_hero.py`, pyopenvdb): big
/// enough that a bake in parts needs less than a whole one.
fn tiled_cloud(dir: &std::path::Path) -> PathBuf {
    let out = dir.join("tiled.vdb");
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tools/make_hero.py");
    let o = std::process::Command::new("/usr/bin/python3")
        .arg(&script)
        .arg(&out)
        .args(["--copies", "3", "3", "3"])
        .output()
        .expect("python3-openvdb (Debian) makes the test cache");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

#[test]
fn bakes_in_parts_equal_whole_bakes_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let path = tiled_cloud(dir.path());
    let whole = bake_job(&path, dir.path().join("whole.exr"), None)
        .run(&|_| {})
        .unwrap();
    assert_eq!(whole.map.stats.parts, 0);
    // The least budget the plan accepts, read from its refusal.
    let least = least_budget(&bake_job(&path, dir.path().join("p.exr"), Some(1 << 20)));
    let mut parts = Vec::new();
    for budget in [least + (1 << 20), least + (4 << 20), least + (12 << 20)] {
        let out = dir.path().join("parts.exr");
        let r = bake_job(&path, out.clone(), Some(budget))
            .run(&|_| {})
            .unwrap();
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&r.map.t), bits(&whole.map.t), "budget {budget}");
        assert_eq!(r.map.slices.len(), 3);
        for (a, b) in r.map.slices.iter().zip(&whole.map.slices) {
            assert_eq!(bits(a), bits(b), "slices, budget {budget}");
        }
        assert_eq!(r.map.stats.lookups, whole.map.stats.lookups);
        let written = std::fs::read(&out).unwrap();
        let reference = std::fs::read(dir.path().join("whole.exr")).unwrap();
        assert!(
            written == reference,
            "budget {budget}: the EXR files differ"
        );
        parts.push(r.map.stats.parts);
    }
    // Smaller budgets take more parts.
    assert!(parts[0] > parts[2] && parts[2] >= 2, "{parts:?}");
    // A pinhole outside the cache and a cube map around a light inside it (six faces, each
    // part swept into every face) are the same bytes in parts too.
    use umbra::bake::{Projection, Resolution};
    let views = [
        (
            Projection::Perspective,
            [1.0, 20.0, 0.5],
            Resolution::Exact(200, 160),
        ),
        (Projection::Cube, [1.0, 1.0, 0.5], Resolution::LongSide(48)),
    ];
    for (projection, at, res) in views {
        let job = |name: &str, budget| {
            let mut j = bake_job(&path, dir.path().join(name), budget);
            j.view.projection = projection;
            j.view.light_pos = Some(at);
            j.view.light_dir = None;
            j.view.res = Some(res);
            j
        };
        let whole = job("view.exr", None).run(&|_| {}).unwrap();
        let r = job("view-parts.exr", Some(least + (4 << 20)))
            .run(&|_| {})
            .unwrap();
        assert!(
            r.map.stats.parts >= 2,
            "{projection:?}: {}",
            r.map.stats.parts
        );
        assert!(r.map.stats.sweep, "{projection:?}");
        assert_eq!(r.map.stats.lookups, whole.map.stats.lookups);
        let a = std::fs::read(dir.path().join("view.exr")).unwrap();
        let b = std::fs::read(dir.path().join("view-parts.exr")).unwrap();
        assert!(a == b, "{projection:?}: the EXR files differ");
    }
}

#[test]
fn ray_path_bakes_in_parts_equal_whole_bakes_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let path = tiled_cloud(dir.path());
    let cases = [
        ("ratio", Interp::Trilinear),
        ("regular", Interp::Nearest),
        ("track-length", Interp::Trilinear),
    ];
    for (name, interp) in cases {
        let job = |out: &str, m: Option<u64>| {
            let mut j = bake_job(&path, dir.path().join(out), m);
            j.settings.estimator = Estimator::from_name(name).unwrap();
            j.settings.options.interp = interp;
            j.settings.options.samples = 4;
            j.settings.std_err = true;
            j
        };
        // Null-collision maps of a whole grid fly block by block (the sweep); in parts they go
        // by rays, so the whole bake they equal is the ray path's.
        let auto = job("auto.exr", None).run(&|_| {}).unwrap();
        assert_eq!(auto.map.stats.sweep, name != "regular", "{name}");
        let mut whole = job("whole.exr", None);
        whole.settings.order = umbra::bake::Order::Rays;
        let whole = whole.run(&|_| {}).unwrap();
        let least = least_budget(&job("p.exr", Some(1 << 20)));
        let r = job("parts.exr", Some(least + (2 << 20)))
            .run(&|_| {})
            .unwrap();
        assert!(
            r.map.stats.parts >= 2,
            "{name}: {} parts",
            r.map.stats.parts
        );
        assert!(!r.map.stats.sweep);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&r.map.t), bits(&whole.map.t), "{name}");
        assert_eq!(
            bits(r.map.std_err.as_ref().unwrap()),
            bits(whole.map.std_err.as_ref().unwrap()),
            "{name}"
        );
        // The largest standard error is reported alike (`--json`'s max_std_err).
        assert_eq!(
            whole.map.stats.max_std_err > 0.0,
            name != "regular",
            "{name}"
        );
        assert_eq!(
            r.map.stats.max_std_err.to_bits(),
            whole.map.stats.max_std_err.to_bits(),
            "{name}"
        );
        for (a, b) in r.map.slices.iter().zip(&whole.map.slices) {
            assert_eq!(bits(a), bits(b), "{name} slices");
        }
        assert_eq!(r.map.stats.lookups, whole.map.stats.lookups, "{name}");
        let written = std::fs::read(dir.path().join("parts.exr")).unwrap();
        let reference = std::fs::read(dir.path().join("whole.exr")).unwrap();
        assert!(written == reference, "{name}: the EXR files differ");
    }
}

/// Ray-marched maps (`riemann`, `jittered`, `mc`) in parts go in the sweep's order as the
/// whole bake does, each pixel keeping its samples' marched optical depths across the parts:
/// the same bytes (T, the standard error, slices). A random march whose samples do not fit
/// beside a part goes by rows on the ray path instead, the same estimate to the kernel's f32
/// positions: at most 1 ulp of T apart.
#[test]
fn marches_in_parts_equal_whole_bakes_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let path = tiled_cloud(dir.path());
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for name in ["riemann", "jittered", "mc"] {
        let job = |out: &str, m: Option<u64>| {
            let mut j = bake_job(&path, dir.path().join(out), m);
            j.settings.estimator = Estimator::from_name(name).unwrap();
            j.settings.options.samples = 4;
            j.settings.std_err = true;
            j
        };
        let whole = job("whole.exr", None).run(&|_| {}).unwrap();
        assert!(whole.map.stats.sweep, "{name}");
        let least = least_budget(&job("p.exr", Some(1 << 20)));
        // The least budget is the ray path's; the sweep keeps the samples' image beside it
        // (300 x 200 pixels x 4 depths x 3 more samples x 8 bytes, 5.5 MiB).
        let r = job("parts.exr", Some(least + (8 << 20)))
            .run(&|_| {})
            .unwrap();
        assert!(
            r.map.stats.parts >= 2,
            "{name}: {} parts",
            r.map.stats.parts
        );
        assert!(r.map.stats.sweep, "{name}");
        assert_eq!(bits(&r.map.t), bits(&whole.map.t), "{name}");
        assert_eq!(
            bits(r.map.std_err.as_ref().unwrap()),
            bits(whole.map.std_err.as_ref().unwrap()),
            "{name}"
        );
        // The largest standard error is reported alike (`--json`'s max_std_err).
        assert_eq!(
            whole.map.stats.max_std_err > 0.0,
            name != "riemann",
            "{name}"
        );
        assert_eq!(
            r.map.stats.max_std_err.to_bits(),
            whole.map.stats.max_std_err.to_bits(),
            "{name}"
        );
        for (a, b) in r.map.slices.iter().zip(&whole.map.slices) {
            assert_eq!(bits(a), bits(b), "{name} slices");
        }
        let written = std::fs::read(dir.path().join("parts.exr")).unwrap();
        let reference = std::fs::read(dir.path().join("whole.exr")).unwrap();
        assert!(written == reference, "{name}: the EXR files differ");
    }
    // 64 samples of `mc` (16 MiB of optical depths at 100 x 80) do not fit beside a part at
    // 2 MiB over the least budget: rows on the ray path, within an ulp.
    let job = |out: &str, m: Option<u64>| {
        let mut j = bake_job(&path, dir.path().join(out), m);
        j.settings.estimator = Estimator::from_name("mc").unwrap();
        j.settings.options.samples = 64;
        j.view.res = Some(umbra::bake::Resolution::Exact(100, 80));
        j
    };
    let whole = job("whole.exr", None).run(&|_| {}).unwrap();
    let least = least_budget(&job("p.exr", Some(1 << 20)));
    let r = job("parts.exr", Some(least + (2 << 20)))
        .run(&|_| {})
        .unwrap();
    assert!(r.map.stats.parts >= 2 && !r.map.stats.sweep);
    for (a, b) in r.map.t.iter().zip(&whole.map.t) {
        assert!(a.to_bits().abs_diff(b.to_bits()) <= 1, "{a} vs {b}");
    }
}

/// `path` with NaN, negative and +Inf voxels written into some of its clouds (pyopenvdb).
fn with_bad_voxels(path: &std::path::Path, out: &std::path::Path) {
    let script = r#"
import sys, pyopenvdb as vdb
g = vdb.read(sys.argv[1], "density")
(lo, hi) = g.evalActiveVoxelBoundingBox()
acc = g.getAccessor()
bad = [float("nan")] * 3 + [-2.5, -0.25] + [float("inf")]
for k, v in enumerate(bad):
    t = (k + 0.5) / len(bad)
    ijk = tuple(int(lo[a] + t * (hi[a] - lo[a])) for a in range(3))
    acc.setValueOn(ijk, v)
vdb.write(sys.argv[2], grids=[g])
"#;
    let o = std::process::Command::new("/usr/bin/python3")
        .args(["-c", script])
        .arg(path)
        .arg(out)
        .output()
        .expect("python3-openvdb (Debian) writes the test cache");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn bakes_in_parts_report_the_bad_voxels_a_whole_bake_reports() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.vdb");
    with_bad_voxels(&tiled_cloud(dir.path()), &path);
    let whole = bake_job(&path, dir.path().join("whole.exr"), None)
        .run(&|_| {})
        .unwrap();
    let least = least_budget(&bake_job(&path, dir.path().join("p.exr"), Some(1 << 20)));
    let parts = bake_job(&path, dir.path().join("parts.exr"), Some(least + (4 << 20)))
        .run(&|_| {})
        .unwrap();
    assert!(parts.map.stats.parts >= 2, "{}", parts.map.stats.parts);
    let text = |r: &umbra::bake::BakeReport| format!("{:?}", r.warnings);
    // 3 NaN and 2 negative voxels set to 0 (the +Inf one is kept, without a warning).
    assert_eq!(text(&whole), "[BadVoxels { nan: 3, negative: 2 }]");
    assert_eq!(text(&parts), text(&whole));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&parts.map.t), bits(&whole.map.t));
}

/// Without `--max-memory`, an exact map of a cache that decodes to more than the implied
/// budget (1 GiB) is swept in parts, never held whole: the same bytes as a whole bake (asked
/// for with a budget it fits in).
#[test]
fn a_big_cache_is_swept_in_parts_without_a_budget() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("big.vdb");
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tools/make_hero.py");
    let o = std::process::Command::new("/usr/bin/python3")
        .arg(&script)
        .arg(&out)
        .args(["--copies", "11", "10", "10"])
        .output()
        .expect("python3-openvdb (Debian) makes the test cache");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(std::fs::metadata(&out).unwrap().len() >= 64 << 20);
    let job = |name: &str, budget| bake_job(&out, dir.path().join(name), budget);
    let implied = job("implied.exr", None).run(&|_| {}).unwrap();
    assert!(
        implied.map.stats.parts >= 2,
        "{} parts",
        implied.map.stats.parts
    );
    let whole = job("whole.exr", Some(64 << 30)).run(&|_| {}).unwrap();
    assert_eq!(whole.map.stats.parts, 0);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&implied.map.t), bits(&whole.map.t));
    let a = std::fs::read(dir.path().join("implied.exr")).unwrap();
    let b = std::fs::read(dir.path().join("whole.exr")).unwrap();
    assert!(a == b, "the EXR files differ");
    // Other estimators load it whole, as before.
    let mut ratio = job("ratio.exr", None);
    ratio.settings.estimator = Estimator::from_name("ratio").unwrap();
    assert!(ratio.plan_bounded().unwrap().is_none());
}

#[test]
fn bakes_in_parts_are_planned_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.exr");
    // Tiles above lower nodes go on the ray path.
    let job = bake_job(&corpus("gen/tiles_mixed.vdb"), out.clone(), Some(1 << 20));
    let e = job.plan_bounded().unwrap_err();
    assert!(e.to_string().contains("at least"), "{e}");
    assert!(!out.exists());
    // A budget the whole grid fits in bakes as usual.
    let job = bake_job(&corpus("gen/cloud_fbm.vdb"), out.clone(), Some(1 << 30));
    assert!(job.plan_bounded().unwrap().is_none());
    assert_eq!(job.run(&|_| {}).unwrap().map.stats.parts, 0);
    // The CLI names the flag and writes nothing.
    let c = dir.path().join("c.exr");
    let cli = |budget: &str| {
        assert_cmd::Command::cargo_bin("umbra")
            .unwrap()
            .args(["bake", corpus("gen/cloud_fbm.vdb").to_str().unwrap()])
            .args(["--light-dir", "0,-1,0", "-o", c.to_str().unwrap()])
            .args(["--max-memory", budget])
            .output()
            .unwrap()
    };
    let o = cli("1M");
    assert_ne!(o.status.code(), Some(0));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--max-memory") && err.contains("at least"),
        "{err}"
    );
    assert!(!c.exists());
    let o = cli("lots");
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn batch_jobs_take_a_memory_budget() {
    let dir = tempfile::tempdir().unwrap();
    let path = tiled_cloud(dir.path());
    let job = |budget: &str| {
        let p = dir.path().join("job.toml");
        std::fs::write(
            &p,
            format!(
                "output = \"{}/{{stem}}_{{light}}.exr\"\n[[inputs]]\nfile = {:?}\n\
                 [[lights]]\nname = \"sun\"\ndir = [0.3, -1, 0.2]\n[bake]\nres = [300, 200]\n\
                 max_memory = {budget:?}\n",
                dir.path().display(),
                path.display().to_string()
            ),
        )
        .unwrap();
        assert_cmd::Command::cargo_bin("umbra")
            .unwrap()
            .args(["batch", p.to_str().unwrap(), "-q", "--force"])
            .output()
            .unwrap()
    };
    // Whole, then in parts: the same bytes.
    assert!(job("64G").status.success());
    let whole = std::fs::read(dir.path().join("tiled_sun.exr")).unwrap();
    let least = match bake_job(&path, dir.path().join("p.exr"), Some(1 << 20)).plan_bounded() {
        Err(umbra::Error::InvalidArgument { reason, .. }) => {
            let at_least = reason.split("at least ").nth(1).unwrap();
            at_least.split(' ').next().unwrap().parse::<f64>().unwrap()
        }
        other => panic!("{other:?}"),
    };
    let o = job(&format!("{}M", least.ceil() + 2.0));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let parts = std::fs::read(dir.path().join("tiled_sun.exr")).unwrap();
    assert!(parts == whole, "the batch map in parts differs");
    // A bad size names the key.
    let o = job("lots");
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("bake.max_memory"), "{err}");
}
