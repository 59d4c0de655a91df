//! `bench srbf --compare`'s glossy baseline, clustered PCA of whole per-vertex transfer
//! matrices ([`MatrixCpca`]): exact on data that is a mean plus two axes per group, and its
//! reported error is the function-space error of its reconstruction. CPU only.

use vkshade::geom::Rng;
use vkshade::kernels::srbf::cpca::CpcaConfig;
use vkshade::kernels::srbf::cpca_matrix::MatrixCpca;
use vkshade::kernels::srbf::transfer::Basis;

/// Vertices that are exactly mean + 2 axes per group (two groups, V = 3, K = 12): with 2
/// clusters and 2 components the reconstruction is exact (to f32 rounding); with 1
/// component it is not, and the error it reports is the reconstruction's.
#[test]
fn matrix_cpca_exact_on_low_rank_groups_and_reports_its_error() {
    let basis = Basis::fibonacci(12);
    let (views, k, n) = (3usize, 12usize, 60usize);
    let d = views * k;
    let mut rng = Rng::new(5);
    let mut groups = Vec::new();
    for _ in 0..2 {
        let g: Vec<Vec<f32>> = (0..3)
            .map(|_| (0..d).map(|_| rng.f32() - 0.5).collect())
            .collect();
        groups.push(g);
    }
    let mut rows = Vec::new();
    for v in 0..n {
        let g = &groups[v % 2];
        let (a, b) = (rng.f32() - 0.5, rng.f32() - 0.5);
        for ((m, u), w) in g[0].iter().zip(&g[1]).zip(&g[2]) {
            rows.push(m + a * u + b * w);
        }
    }
    let cfg = |m| CpcaConfig {
        clusters: 2,
        components: m,
        ..CpcaConfig::default()
    };
    let exact = MatrixCpca::compress(&basis, &rows, n, views, &cfg(2)).unwrap();
    assert!(exact.rel_l2 < 1e-4, "{}", exact.rel_l2);
    for v in 0..n {
        let r = exact.reconstruct(v);
        for x in 0..d {
            let want = rows[v * d + x] as f64;
            assert!(
                (r[x] - want).abs() < 1e-3,
                "v {v} x {x}: {} vs {want}",
                r[x]
            );
        }
    }
    let lossy = MatrixCpca::compress(&basis, &rows, n, views, &cfg(1)).unwrap();
    assert!(lossy.rel_l2 > 1e-2, "{}", lossy.rel_l2);
    // The reported error is the function-space error of the reconstruction.
    let gram = basis.gram();
    let norm = |t: &[f64]| -> f64 {
        (0..views)
            .map(|j| {
                let r = &t[j * k..(j + 1) * k];
                (0..k)
                    .map(|a| (0..k).map(|b| r[a] * gram[a * k + b] * r[b]).sum::<f64>())
                    .sum::<f64>()
            })
            .sum()
    };
    let (mut e2, mut n2) = (0.0, 0.0);
    for v in 0..n {
        let orig: Vec<f64> = rows[v * d..(v + 1) * d].iter().map(|x| *x as f64).collect();
        let diff: Vec<f64> = lossy
            .reconstruct(v)
            .iter()
            .zip(&orig)
            .map(|(a, b)| a - b)
            .collect();
        e2 += norm(&diff);
        n2 += norm(&orig);
    }
    let measured = (e2 / n2).sqrt();
    assert!(
        (measured - lossy.rel_l2).abs() < 0.05 * lossy.rel_l2,
        "reported {} vs measured {measured}",
        lossy.rel_l2
    );
}

/// Bad settings and sizes are refused with a message naming the problem, never a panic.
#[test]
fn compare_and_matrix_cpca_refuse_bad_input() {
    use vkshade::bench::srbf_compare::CompareConfig;
    let bad_bytes = CompareConfig {
        bytes: vec![4],
        ..CompareConfig::default()
    };
    let e = bad_bytes.check().unwrap_err().to_string();
    assert!(e.contains("--bytes"), "{e}");
    let none = CompareConfig {
        diffuse: false,
        glossy: false,
        ..CompareConfig::default()
    };
    assert!(none.check().unwrap_err().to_string().contains("nothing"));
    assert!(CompareConfig::default().check().is_ok());
    let basis = Basis::fibonacci(8);
    let cfg = CpcaConfig {
        clusters: 2,
        components: 1,
        ..CpcaConfig::default()
    };
    let e = MatrixCpca::compress(&basis, &[0.0; 10], 2, 1, &cfg)
        .unwrap_err()
        .to_string();
    assert!(e.contains("10 coefficients"), "{e}");
    let zero = CpcaConfig {
        components: 0,
        ..cfg
    };
    assert!(MatrixCpca::compress(&basis, &[0.0; 16], 2, 1, &zero).is_err());
}

/// The CPCA matched to CTA's total storage: the cluster count chosen keeps its amortised
/// bytes per vertex (as `MatrixCpca::bytes_per_vertex` counts them) within the total, and
/// one cluster more would not.
#[test]
fn matched_total_cpca_fits_the_budget_and_one_more_cluster_does_not() {
    use vkshade::bench::srbf_compare::matrix_cpca_clusters_within;
    let basis = Basis::fibonacci(12);
    let (views, n, m) = (3usize, 60usize, 2usize);
    let mut rng = Rng::new(9);
    let rows: Vec<f32> = (0..n * views * 12).map(|_| rng.f32() - 0.5).collect();
    let amortised = |clusters| {
        let cfg = CpcaConfig {
            clusters,
            components: m,
            ..CpcaConfig::default()
        };
        MatrixCpca::compress(&basis, &rows, n, views, &cfg)
            .unwrap()
            .bytes_per_vertex()
            .1
    };
    for total in [20.0, 60.0, 97.5, 150.0] {
        let c = matrix_cpca_clusters_within(total, m, views, 12, n);
        if c > 0 {
            assert!(amortised(c) <= total, "{c} clusters exceed {total}");
        }
        assert!(amortised(c + 1) > total, "{} clusters fit {total}", c + 1);
    }
    // One cluster's tables (3 matrices of 144 B) exceed the 2 B per vertex that 10 leaves
    // beside the 8 streamed, over 60 vertices.
    assert_eq!(matrix_cpca_clusters_within(10.0, m, views, 12, n), 0);
    assert_eq!(matrix_cpca_clusters_within(f64::NAN, m, views, 12, n), 0);
    assert_eq!(
        matrix_cpca_clusters_within(f64::INFINITY, m, views, 12, n),
        n
    );
}
