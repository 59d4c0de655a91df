//! `vkshade validate` on a reduced set of cases (through its library function, GPU-assisted
//! rows in the real `vkshade` binary).

mod scratch;
use std::time::Duration;
use vkshade::app::Gpu;
use vkshade::app::validate::{self, FeatureSet, Status, ValidateConfig};

fn gpu() -> Gpu {
    Gpu {
        device: Default::default(),
        validate: true,
        validation: None,
    }
}

fn fresh_dir(name: &str) -> std::path::PathBuf {
    let d = scratch::dir(&format!("validate-{name}"));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Two cases, each under the standard features and under GPU-assisted validation: a row
/// each, the pipelines they dispatch named, zero messages; a GPU-assisted row is clean or the
/// layer's known problem (never messages, never a failure).
#[test]
fn validate_runs_the_cases_and_reports_rows_without_messages() {
    let cfg = ValidateConfig {
        cases: vec!["ao-fixed-cut".into(), "bench-peak".into()],
        out: fresh_dir("validate"),
        gpu_assisted_exe: Some(env!("CARGO_BIN_EXE_vkshade").into()),
        gpu_assisted_timeout: Duration::from_secs(20),
        coverage: true,
    };
    let r = validate::run(&cfg, &gpu(), &mut |l| eprintln!("{l}")).unwrap();
    eprintln!("{}", validate::table(&r));
    assert_eq!(r.rows.len(), 4);
    let names: Vec<(&str, FeatureSet)> = r
        .rows
        .iter()
        .map(|r| (r.case.as_str(), r.features))
        .collect();
    assert_eq!(
        names,
        [
            ("ao-fixed-cut", FeatureSet::Standard),
            ("bench-peak", FeatureSet::Standard),
            ("ao-fixed-cut", FeatureSet::GpuAssisted),
            ("bench-peak", FeatureSet::GpuAssisted),
        ]
    );
    for row in &r.rows[..2] {
        assert_eq!(row.status, Status::Clean, "{row:?}");
        assert!(row.messages.is_empty());
        assert!(row.seconds > 0.0);
    }
    let p = &r.rows[0].pipelines;
    for name in ["ao/skin", "ao/fixed"] {
        assert!(p.iter().any(|x| x == name), "{name} not in {p:?}");
    }
    assert!(r.rows[1].pipelines.iter().any(|x| x == "bench/fma"));
    for row in &r.rows[2..] {
        assert!(
            matches!(row.status, Status::Clean | Status::LayerProblem(_)),
            "{row:?}"
        );
        assert!(row.messages.is_empty(), "{row:?}");
    }
    // A subset leaves the coverage check out (it would list every other module).
    assert!(!r.coverage_checked && r.not_exercised.is_empty());
    assert!(r.passed());
    // An unknown case is refused, naming the cases there are.
    let e = match validate::select(&["nope".into()]) {
        Ok(_) => panic!("an unknown case was accepted"),
        Err(e) => e.to_string(),
    };
    assert!(e.contains("nope") && e.contains("frame"), "{e}");
    // The cases' outputs (27 MB) are not left behind in the temporary folder.
    let _ = std::fs::remove_dir_all(&cfg.out);
}
