//! Render one hazcam stereo pair of a textured yard and write it as `left.pgm` and `right.pgm`.
//!
//! `cargo run --release -p sim-host --example render_pair -- OUT_DIR [flat|slope|cross] [SEED]`
//!
//! The rover stands at the origin heading north, its reference point 0.25 m above the ground
//! (camera 0.85 m up); `slope` is a 10 deg slope rising to the north (seen face on), `cross`
//! a 10 deg slope rising to the east. Sun 40 deg up in the south-east.

use sim_host::devices::hazcam_calibration;
use sim_host::render::{
    AlbedoTexture, CameraPose, HeightFn, RenderSettings, StereoRenderer, Sun, TextureParams,
    TexturedSurface,
};
use std::io::Write;
use std::sync::Arc;

fn write_pgm(
    path: &std::path::Path,
    width: usize,
    height: usize,
    data: &[u8],
) -> anyhow::Result<()> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    write!(f, "P5\n{width} {height}\n255\n")?;
    f.write_all(data)?;
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let out = std::path::PathBuf::from(args.next().unwrap_or_else(|| ".".into()));
    let terrain = args.next().unwrap_or_else(|| "flat".into());
    let seed: u64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(1);
    std::fs::create_dir_all(&out)?;
    let texture = Arc::new(AlbedoTexture::new(TextureParams {
        seed,
        ..TextureParams::default()
    }));
    let slope = 10f64.to_radians().tan();
    let height: Box<dyn Fn(f64, f64) -> f64 + Sync> = match terrain.as_str() {
        "slope" => Box::new(move |x, _y| slope * x),
        "cross" => Box::new(move |_x, y| slope * y),
        _ => Box::new(|_x, _y| 0.0),
    };
    let surface = TexturedSurface::new(HeightFn(height), texture);
    let calib = hazcam_calibration();
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let pose = CameraPose::from_rover(identity, [0.0, 0.0, -0.25], &calib);
    let mut renderer = StereoRenderer::new(calib, RenderSettings::default());
    let sun = Sun::from_azimuth_elevation(135f64.to_radians(), 40f64.to_radians());
    let (w, h) = (rover_hal::IMAGE_WIDTH_PX, rover_hal::IMAGE_HEIGHT_PX);
    let mut left = vec![0u8; w * h];
    let mut right = vec![0u8; w * h];
    let t0 = std::time::Instant::now();
    let stats = renderer
        .render(&surface, &pose, &sun, seed, &mut left, &mut right)
        .map_err(|e| anyhow::anyhow!("render failed: {e:?}"))?;
    println!(
        "rendered in {:.1} ms: {stats:?}",
        t0.elapsed().as_secs_f64() * 1e3
    );
    write_pgm(&out.join("left.pgm"), w, h, &left)?;
    write_pgm(&out.join("right.pgm"), w, h, &right)?;
    println!("wrote {}/left.pgm and right.pgm", out.display());
    Ok(())
}
