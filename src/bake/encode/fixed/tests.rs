use super::*;

const FORMATS: [DeepFormat; 7] = [
    DeepFormat::Fourier(3),
    DeepFormat::Fourier(15),
    DeepFormat::Fourier(31),
    DeepFormat::Moments(4),
    DeepFormat::Moments(6),
    DeepFormat::Avsm(4),
    DeepFormat::Avsm(8),
];

/// Profiles a texel meets: empty, a thin and a thick slab, two slabs, a ramp, an opaque
/// surface behind fog, opaque at the start, a long noisy climb.
fn profiles() -> Vec<NormProfile> {
    let r = (0.0, 10.0);
    let mk = |t: &[f64], tau: &[f64], o: Option<f64>| NormProfile::new(t, tau, o, r).unwrap();
    let mut noisy_t = vec![0.0];
    let mut noisy_tau = vec![0.0];
    let mut s = 0.3f64;
    for i in 1..200 {
        s = (s * 3.9 * (1.0 - s)).clamp(0.01, 0.99);
        noisy_t.push(1.0 + 8.0 * i as f64 / 199.0);
        noisy_tau.push(noisy_tau[i - 1] + 0.1 * s);
    }
    vec![
        mk(&[], &[], None),
        mk(&[0.0, 4.0, 4.5, 10.0], &[0.0, 0.0, 0.3, 0.3], None),
        mk(&[0.0, 2.0, 8.0, 10.0], &[0.0, 0.0, 12.0, 12.0], None),
        mk(
            &[0.0, 1.0, 2.0, 6.0, 7.0, 10.0],
            &[0.0, 0.0, 1.0, 1.0, 1.5, 1.5],
            None,
        ),
        mk(&[0.0, 10.0], &[0.0, 3.0], None),
        mk(&[0.0, 3.0, 5.0, 10.0], &[0.0, 0.0, 0.5, 0.5], Some(6.0)),
        mk(&[0.0, 10.0], &[0.0, 1.0], Some(0.0)),
        mk(&noisy_t, &noisy_tau, None),
    ]
}

/// The largest error over 20001 depths, and whether T is in [0, 1] and never grows.
fn dense(f: DeepFormat, c: &[f32], p: &NormProfile) -> (f64, bool) {
    let mut worst = 0.0f64;
    let mut prev = 1.0f64 + 1e-12;
    let mut ok = true;
    for i in 0..=20_000 {
        let u = i as f64 / 20_000.0;
        let t = f.transmittance(c, u);
        ok &= (0.0..=1.0).contains(&t) && t <= prev + 1e-12;
        prev = t;
        worst = worst.max((t - (-p.at(u, false)).exp()).abs());
    }
    // The limits from the left at the profile's jumps (an opaque depth).
    for u in p.jumps() {
        let t = (-f.tau(c, u, true)).exp();
        worst = worst.max((t - (-p.at(u, true)).exp()).abs());
    }
    (worst, ok)
}

#[test]
fn formats_parse_and_name_their_channels() {
    for f in FORMATS {
        let back: DeepFormat = f.to_string().parse().unwrap();
        assert_eq!(back, f);
        assert_eq!(f.channel_names().len(), f.channels());
    }
    for bad in [
        "fourier:4",
        "fourier:1",
        "moments:5",
        "avsm:1",
        "avsm:33",
        "avsm",
        "x:3",
        "avsm:k",
    ] {
        let e = bad.parse::<DeepFormat>().unwrap_err().to_string();
        assert!(e.contains("deep-format"), "{e}");
    }
    assert_eq!(
        DeepFormat::Fourier(5).channel_names(),
        ["a0", "a1", "b1", "a2", "b2"]
    );
}

#[test]
fn reconstructions_are_monotone_and_bounded_by_their_reported_error() {
    for p in profiles() {
        for f in FORMATS {
            let c = f.encode(&p);
            assert_eq!(c.len(), f.channels(), "{f}");
            let e = texel_error(f, &c, &p, 1e-4);
            let (worst, ok) = dense(f, &c, &p);
            assert!(ok, "{f}: T leaves [0, 1] or grows with depth on {p:?}");
            assert!(
                worst <= e.bound + 1e-12,
                "{f}: error {worst} above its bound {} on {p:?}",
                e.bound
            );
            assert!(e.seen <= e.bound && e.bound <= 1.0);
        }
    }
}

#[test]
fn the_bound_is_tight_after_refinement() {
    // Refined to a threshold of 1e-3, the bound is within 1e-3 of the dense maximum.
    for p in profiles() {
        for f in FORMATS {
            let c = f.encode(&p);
            let e = texel_error(f, &c, &p, 1e-3);
            let (worst, _) = dense(f, &c, &p);
            assert!(
                e.bound <= worst.max(1e-3) + 1e-3,
                "{f}: bound {} vs {worst} on {p:?}",
                e.bound
            );
        }
    }
}

#[test]
fn nodes_that_suffice_are_exact_and_fourier_ends_at_the_total() {
    let p = &profiles()[3];
    let f = DeepFormat::Avsm(8);
    let c = f.encode(p);
    assert!(texel_error(f, &c, p, 1e-6).bound < 2e-6);
    for p in profiles() {
        let c = DeepFormat::Fourier(15).encode(&p);
        let far = fourier::tau(&c, 1.0);
        assert!(
            (far - p.total()).abs() <= 1e-5 * p.total().max(1.0),
            "{far} vs {}",
            p.total()
        );
    }
}

#[test]
fn more_channels_fit_better() {
    // On the noisy climb every family improves with its budget.
    let p = &profiles()[7];
    let err = |f: DeepFormat| texel_error(f, &f.encode(p), p, 1e-4).bound;
    assert!(err(DeepFormat::Fourier(31)) < err(DeepFormat::Fourier(3)));
    assert!(err(DeepFormat::Moments(6)) < err(DeepFormat::Moments(4)));
    assert!(err(DeepFormat::Avsm(8)) < err(DeepFormat::Avsm(4)));
}

#[test]
fn the_moments_power_table_is_powi() {
    for x in [-1.0, -0.731, -0.2, 0.0, 1e-3, 0.3333, 0.77, 1.0] {
        let t = moments::powers(x);
        for (e, v) in t.iter().enumerate() {
            assert_eq!(v.to_bits(), x.powi(e as i32).to_bits(), "{x}^{e}");
        }
    }
}
