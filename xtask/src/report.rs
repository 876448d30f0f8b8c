//! Checks of the per-run outputs in `cargo xtask test` (also `cargo xtask report`): a real run
//! of `slope-10-cross`, `evo_ape` and `evo_rpe` with their default options on every TUM output
//! (evo installed in a virtual environment under `target/`), and headless-Chromium
//! screenshots of the run's `report.html` and of the main command's H05 Fig. 9 figure, each
//! checked to be drawn (not blank, with coloured curves).
//!
//! [`screenshot`] takes any HTML or SVG file, so other reports (campaigns) can use it too.

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The evo release the check installs (PyPI).
pub const EVO_VERSION: &str = "1.38.1";
/// The headless browser (Debian package and command `chromium`).
const CHROMIUM: &str = "chromium";
/// Where the checks write (relative to the workspace root).
const OUT: &str = "target/xtask-report";

/// A screenshot and what it shows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Screenshot {
    /// Width, px.
    pub width: u32,
    /// Height, px.
    pub height: u32,
    /// Fraction of pixels that are not white (any channel below 245).
    pub non_white: f64,
    /// Fraction of pixels that are coloured (largest minus smallest channel above 60): the
    /// curves, bands and bars of the figures, absent from a blank or error page.
    pub coloured: f64,
}

impl Screenshot {
    /// Fails unless at least `non_white` of the pixels are not white and `coloured` of them
    /// are coloured.
    pub fn check(&self, what: &str, non_white: f64, coloured: f64) -> Result<()> {
        println!(
            "{what}: {}x{} px, {:.2} % not white, {:.3} % coloured",
            self.width,
            self.height,
            100.0 * self.non_white,
            100.0 * self.coloured
        );
        if self.non_white < non_white || self.coloured < coloured {
            bail!(
                "{what}: the screenshot looks blank ({:.2} % not white, need {:.2} %; {:.3} % \
                 coloured, need {:.3} %)",
                100.0 * self.non_white,
                100.0 * non_white,
                100.0 * self.coloured,
                100.0 * coloured
            );
        }
        Ok(())
    }
}

fn have(program: &str, arg: &str) -> bool {
    Command::new(program)
        .arg(arg)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn run(cmd: &mut Command) -> Result<()> {
    let shown = format!("{cmd:?}");
    let status = cmd
        .status()
        .with_context(|| format!("cannot start {shown}"))?;
    if !status.success() {
        bail!("failed ({status}): {shown}");
    }
    Ok(())
}

/// Install Debian's `chromium` with apt-get when it is missing.
pub fn ensure_chromium() -> Result<()> {
    if have(CHROMIUM, "--version") {
        return Ok(());
    }
    println!("{CHROMIUM} missing: installing it with apt-get");
    let apt = run(Command::new("apt-get").args(["update", "-qq"])).and_then(|_| {
        run(Command::new("apt-get")
            .args(["install", "-y", "-qq", CHROMIUM])
            .env("DEBIAN_FRONTEND", "noninteractive"))
    });
    if apt.is_err() || !have(CHROMIUM, "--version") {
        bail!(
            "{CHROMIUM} is required for the report screenshots and could not be installed \
             automatically: install it with `sudo apt-get install -y chromium` (Debian/Ubuntu) \
             or your system's Chromium package, then run again"
        );
    }
    Ok(())
}

/// Render `page` (an HTML or SVG file) in headless Chromium at `window` (width, height) px,
/// write the PNG to `png` and measure it.
pub fn screenshot(page: &Path, png: &Path, window: (u32, u32)) -> Result<Screenshot> {
    ensure_chromium()?;
    let page = page
        .canonicalize()
        .with_context(|| format!("no page {}", page.display()))?;
    if let Some(dir) = png.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    let _ = std::fs::remove_file(png);
    let profile = std::env::temp_dir().join(format!("xtask-chromium-{}", std::process::id()));
    let output = Command::new("timeout")
        .arg("180")
        .arg(CHROMIUM)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("--screenshot={}", png.display()))
        .arg(format!("--window-size={},{}", window.0, window.1))
        .arg(format!("file://{}", page.display()))
        .stdin(Stdio::null())
        .output()
        .with_context(|| format!("cannot start {CHROMIUM}"))?;
    let _ = std::fs::remove_dir_all(&profile);
    if !png.exists() {
        let err = String::from_utf8_lossy(&output.stderr);
        let tail: Vec<&str> = err.lines().rev().take(10).collect();
        bail!(
            "{CHROMIUM} wrote no screenshot of {} ({}): {}",
            page.display(),
            output.status,
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        );
    }
    measure_png(png)
}

/// Decode `png` and count its non-white and coloured pixels.
pub fn measure_png(png: &Path) -> Result<Screenshot> {
    let file =
        std::fs::File::open(png).with_context(|| format!("cannot open {}", png.display()))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    decoder.set_transformations(png::Transformations::normalize_to_color8());
    let mut reader = decoder.read_info().context("not a PNG")?;
    let size = reader
        .output_buffer_size()
        .context("PNG too large to decode")?;
    let mut buf = vec![0u8; size];
    let info = reader
        .next_frame(&mut buf)
        .context("cannot decode the PNG")?;
    let channels = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => bail!("indexed PNG after expansion"),
    };
    let colour = if channels >= 3 { 3 } else { 1 };
    let (mut non_white, mut coloured, mut total) = (0u64, 0u64, 0u64);
    for row in buf[..info.buffer_size()].chunks_exact(info.line_size) {
        for px in row
            .chunks_exact(channels)
            .take(info.width as usize)
            .map(|p| &p[..colour])
        {
            total += 1;
            let (lo, hi) = px
                .iter()
                .fold((u8::MAX, u8::MIN), |a, &c| (a.0.min(c), a.1.max(c)));
            if lo < 245 {
                non_white += 1;
            }
            if hi - lo > 60 {
                coloured += 1;
            }
        }
    }
    let total = total.max(1) as f64;
    Ok(Screenshot {
        width: info.width,
        height: info.height,
        non_white: non_white as f64 / total,
        coloured: coloured as f64 / total,
    })
}

/// The evo commands: a virtual environment `target/evo-venv` with evo [`EVO_VERSION`],
/// created and installed from PyPI when missing. Returns its `bin` directory.
pub fn ensure_evo() -> Result<PathBuf> {
    let venv = Path::new("target").join("evo-venv");
    let bin = venv.join("bin");
    let marker = venv.join(format!("evo-{EVO_VERSION}.installed"));
    if marker.exists() && bin.join("evo_ape").exists() {
        return Ok(bin);
    }
    println!("installing evo {EVO_VERSION} into {}", venv.display());
    let python = if have("python3", "--version") {
        "python3"
    } else {
        "python"
    };
    run(Command::new(python).args(["-m", "venv"]).arg(&venv)).context(
        "cannot create a Python virtual environment for evo: install python3 with venv \
         (Debian: `apt-get install -y python3-venv`)",
    )?;
    run(Command::new(bin.join("pip")).args([
        "install",
        "-q",
        "--disable-pip-version-check",
        &format!("evo=={EVO_VERSION}"),
    ]))
    .with_context(|| format!("cannot install evo {EVO_VERSION} from PyPI"))?;
    std::fs::write(&marker, "")?;
    Ok(bin)
}

/// `evo_ape tum truth.tum X.tum` and `evo_rpe tum truth.tum X.tum` with default options for
/// every TUM file `X` of `dir`; fails if any of them fails. Prints each RMSE.
pub fn evo_check(dir: &Path) -> Result<()> {
    let bin = ensure_evo()?;
    let truth = dir.join("truth.tum");
    if !truth.exists() {
        bail!("no truth.tum in {}", dir.display());
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "tum") && *p != truth)
        .collect();
    files.sort();
    if files.is_empty() {
        bail!("no estimate TUM files in {}", dir.display());
    }
    for file in &files {
        for tool in ["evo_ape", "evo_rpe"] {
            let out = Command::new(bin.join(tool))
                .arg("tum")
                .arg(&truth)
                .arg(file)
                .env("MPLBACKEND", "Agg")
                .output()
                .with_context(|| format!("cannot start {tool}"))?;
            let text = String::from_utf8_lossy(&out.stdout);
            let rmse = text
                .lines()
                .find(|l| l.trim_start().starts_with("rmse"))
                .map(|l| l.split_whitespace().last().unwrap_or("?").to_string());
            let name = file.file_name().unwrap_or_default().to_string_lossy();
            match (out.status.success(), rmse) {
                (true, Some(r)) => println!("{tool} tum truth.tum {name}: rmse {r} m"),
                _ => bail!(
                    "{tool} tum {} {} failed ({}):\n{}{}",
                    truth.display(),
                    file.display(),
                    out.status,
                    text,
                    String::from_utf8_lossy(&out.stderr)
                ),
            }
        }
    }
    Ok(())
}

fn cargo() -> Command {
    Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
}

/// The report checks: run `slope-10-cross` (simulated-time counter), evo on its TUM outputs,
/// a screenshot of its `report.html`; the main command's comparison and a screenshot of its
/// H05 Fig. 9 figure.
pub fn report_checks() -> Result<()> {
    let out = Path::new(OUT);
    let run_dir = out.join("run");
    let _ = std::fs::remove_dir_all(out);
    run(cargo()
        .args(["run", "--release", "--quiet", "-p", "sim-host", "--", "run"])
        .arg("scenarios/slope-10-cross.toml")
        .arg("--out")
        .arg(&run_dir)
        .arg("--sim-counter"))?;
    evo_check(&run_dir)?;
    let shot = screenshot(
        &run_dir.join("report.html"),
        &out.join("report.png"),
        (1280, 6000),
    )?;
    shot.check("report.html screenshot", 0.05, 0.005)?;
    let compare_dir = out.join("compare");
    run(cargo()
        .args([
            "run",
            "--release",
            "--quiet",
            "-p",
            "sim-host",
            "--",
            "compare",
        ])
        .arg("--out")
        .arg(&compare_dir))?;
    let shot = screenshot(
        &compare_dir.join("fig9-top-view.svg"),
        &out.join("fig9-top-view.png"),
        (980, 360),
    )?;
    shot.check("H05 Fig. 9 figure screenshot", 0.05, 0.003)?;
    println!("screenshots in {}", out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A white RGBA image of `w` x `h` with a red square of `side` px and a grey line.
    fn write_png(path: &Path, w: u32, h: u32, side: u32) {
        let mut data = vec![255u8; (w * h * 4) as usize];
        for y in 0..h {
            for x in 0..w {
                let i = ((y * w + x) * 4) as usize;
                if x < side && y < side {
                    data[i..i + 3].copy_from_slice(&[214, 39, 40]);
                } else if y == h - 1 {
                    data[i..i + 3].copy_from_slice(&[90, 90, 90]);
                }
            }
        }
        let file = std::fs::File::create(path).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w, h);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header().unwrap().write_image_data(&data).unwrap();
    }

    #[test]
    fn report_png_measure_counts_non_white_and_coloured_pixels() {
        let dir = std::env::temp_dir().join(format!("xtask-png-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.png");
        write_png(&p, 100, 50, 10);
        let s = measure_png(&p).unwrap();
        assert_eq!((s.width, s.height), (100, 50));
        // 100 red pixels and 100 grey (the last row) of 5000.
        assert!((s.non_white - 200.0 / 5000.0).abs() < 1e-12, "{s:?}");
        assert!((s.coloured - 100.0 / 5000.0).abs() < 1e-12, "{s:?}");
        assert!(s.check("test", 0.03, 0.01).is_ok());
        write_png(&p, 100, 50, 0);
        let blank = measure_png(&p).unwrap();
        assert_eq!(blank.coloured, 0.0);
        assert!(blank.check("blank", 0.03, 0.01).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
