//! `fuzz-hal --frames N [--seed S] [--no-vo] [--trace]`: run the adversarial-HAL fuzzer, print
//! the summary, exit with status 1 on any invariant violation (`--trace`: with the last
//! garbage answers before each).

use fuzz_hal::{run, FuzzConfig};

fn main() {
    let mut config = FuzzConfig {
        frames: 200_000,
        seed: 1,
        vo: true,
        trace: false,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut number = |name: &str| -> u64 {
            let v = args.next().unwrap_or_default().replace('_', "");
            v.parse()
                .or_else(|_| v.parse::<f64>().map(|f| f as u64))
                .unwrap_or_else(|_| {
                    eprintln!("{name} needs a number, got {v:?}");
                    std::process::exit(2)
                })
        };
        match a.as_str() {
            "--frames" => config.frames = number("--frames"),
            "--seed" => config.seed = number("--seed"),
            "--no-vo" => config.vo = false,
            "--trace" => config.trace = true,
            _ => {
                eprintln!("usage: fuzz-hal --frames N [--seed S] [--no-vo] [--trace]");
                std::process::exit(2)
            }
        }
    }
    // Panics are caught and reported as violations; keep their messages short.
    std::panic::set_hook(Box::new(|info| {
        eprintln!("fuzz-hal: flight software panic: {info}")
    }));
    let report = run(config, |r| {
        eprintln!(
            "  {} frames, {} violations, {:.0} frames/s",
            r.frames,
            r.violations,
            r.frames as f64 / r.wall_s.max(1e-9)
        )
    });
    print!("{}", report.summary(&config));
    if report.violations > 0 {
        std::process::exit(1);
    }
}
