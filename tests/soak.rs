//! The short soak CI runs: 400 AO frames under validation. Its own test binary: host RSS is
//! the process's, so no other test may run beside it.

mod scratch;
use vkshade::app::Gpu;
use vkshade::app::validate::{self, SoakKernel, soak_run};
use vkshade::bench::soak::SoakConfig;

fn gpu() -> Gpu {
    Gpu {
        device: Default::default(),
        validate: true,
        validation: None,
    }
}

/// 400 AO frames under validation: device memory exactly flat after the warm-up, host RSS
/// within the soak's tolerance, no message, no leak (soak_run fails otherwise).
#[test]
fn a_short_soak_stays_flat() {
    let cfg = SoakConfig::new(400);
    let r = soak_run(&gpu(), SoakKernel::Ao, &cfg, &mut |l| eprintln!("{l}")).unwrap();
    assert!(r.verdict.problems.is_empty(), "{:?}", r.verdict);
    assert_eq!(r.samples.len(), 1 + 400 / cfg.every);
    assert!(
        r.samples
            .iter()
            .all(|s| s.rss_bytes > 0 && s.device_used_bytes > 0)
    );
    let dir = scratch::fresh("soak");
    validate::write_soak(&dir, &r).unwrap();
    let csv = std::fs::read_to_string(dir.join("soak.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + r.samples.len());
}
