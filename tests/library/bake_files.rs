//! Bake outputs and refusals: the PNG preview, atomic writes that leave nothing on failure,
//! and cameras that cannot be framed.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support;

use bake_support::{box_volume, ortho, prov, read_exr, regular};
use umbra::bake::{bake, write_exr, write_png, Camera, Projection, View};
use umbra::internals::output::write_atomic;
use umbra::internals::tree::TreeBuilder;
use umbra::{Interp, Volume};

#[test]
fn png_preview_is_t_in_8_bits() {
    let dir = tempfile::tempdir().unwrap();
    let vol = box_volume();
    let cam = Camera::frame(&ortho([0.0, 0.0, 1.0], 30, 20), &vol.box_corners().unwrap()).unwrap();
    let map = bake(&vol, &cam, &regular(Interp::Nearest), &|_| {}).unwrap();
    let p = dir.path().join("p.png");
    write_png(&p, &map, false).unwrap();
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&p).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (30, 20));
    assert_eq!(info.color_type, png::ColorType::Grayscale);
    for (b, t) in buf.iter().zip(&map.t) {
        assert_eq!(*b, (t.clamp(0.0, 1.0) * 255.0).round() as u8);
    }
}

#[test]
fn atomic_writes_leave_nothing_on_failure() {
    let dir = tempfile::tempdir().unwrap();
    let listing = || {
        let mut v: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    let target = dir.path().join("out.exr");
    // The writer fails after a megabyte.
    let e = write_atomic(&target, false, |w| {
        std::io::Write::write_all(w, &vec![7u8; 1 << 20]).unwrap();
        Err("disk on fire".into())
    });
    assert!(e.unwrap_err().to_string().contains("disk on fire"));
    assert!(listing().is_empty(), "{:?}", listing());
    // The writer panics.
    let r = std::panic::catch_unwind(|| {
        let _ = write_atomic(&target, false, |w| {
            std::io::Write::write_all(w, b"partial").unwrap();
            panic!("boom")
        });
    });
    assert!(r.is_err());
    assert!(listing().is_empty(), "{:?}", listing());
    // An existing file is neither overwritten without permission nor damaged by a failure.
    std::fs::write(&target, b"precious").unwrap();
    assert!(write_atomic(&target, false, |_| Ok(())).is_err());
    assert!(write_atomic(&target, true, |_| Err("nope".into())).is_err());
    assert_eq!(std::fs::read(&target).unwrap(), b"precious");
    assert_eq!(listing(), ["out.exr"]);
    // A missing directory or a directory as target: an error, nothing created.
    let vol = box_volume();
    let cam = Camera::frame(&ortho([0.0, 0.0, 1.0], 4, 4), &vol.box_corners().unwrap()).unwrap();
    let map = bake(&vol, &cam, &regular(Interp::Nearest), &|_| {}).unwrap();
    assert!(write_exr(&dir.path().join("no/such/dir.exr"), &map, &prov(&vol), true).is_err());
    assert!(write_exr(dir.path(), &map, &prov(&vol), true).is_err());
    assert_eq!(listing(), ["out.exr"]);
    // Success replaces it whole.
    write_exr(&target, &map, &prov(&vol), true).unwrap();
    assert_eq!(read_exr(&target).ch["T"], map.t);
    assert_eq!(listing(), ["out.exr"]);
}

#[test]
fn bad_cameras_are_refused() {
    let vol = box_volume();
    let c = vol.box_corners().unwrap();
    assert!(Camera::frame(&ortho([0.0; 3], 8, 8), &c).is_err());
    assert!(Camera::frame(&ortho([1.0, 0.0, 0.0], 0, 8), &c).is_err());
    assert!(Camera::frame(&ortho([1.0, 0.0, 0.0], 70_000, 8), &c).is_err());
    let inside = View {
        light_pos: Some(vol.to_world([64.0; 3]).to_array()),
        ..ortho([1.0, 0.0, 0.0], 8, 8)
    };
    let e = Camera::frame(&inside, &c).unwrap_err().to_string();
    assert!(e.contains("inside"), "{e}");
    let p = View {
        projection: Projection::Perspective,
        ..inside
    };
    assert!(Camera::frame(&p, &c).is_err());
    assert!(Camera::frame(
        &View {
            fov_deg: Some(60.0),
            ..p
        },
        &c
    )
    .is_ok());
    assert!(Camera::frame(
        &View {
            fov_deg: Some(180.0),
            ..p
        },
        &c
    )
    .is_err());
    let empty = Volume::from_tree(
        "e".into(),
        TreeBuilder::new(0.0).build(),
        box_volume().world_from_index_rows(),
        1.0,
    )
    .unwrap();
    assert!(empty.box_corners().is_err());
}
