//! The `bench` subcommand and the grid parameters shared with the node.

use anyhow::Result;
use sph::{synth, Bounds, GridGeometry, KernelKind, Mode, Search, Transfer, TransferConfig};
use std::time::Instant;

/// Where the grid lies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BoundsArg {
    /// From the scene's walls (first bodies frame of each simulation).
    Auto,
    /// A fixed rectangle.
    Fixed(Bounds),
}

fn parse_bounds(s: &str) -> Result<BoundsArg, String> {
    if s == "auto" {
        return Ok(BoundsArg::Auto);
    }
    s.parse::<Bounds>().map(BoundsArg::Fixed).map_err(|e| e.to_string())
}

/// Grid and kernel parameters.
#[derive(clap::Args, Debug, Clone)]
pub struct GridArgs {
    /// Smoothing kernel: poly6, spiky, gaussian (sigma = h/3) or gaussian:SIGMA_OVER_H.
    #[arg(long, default_value = "poly6")]
    pub kernel: KernelKind,
    /// Kernel support radius (world units).
    #[arg(long, default_value_t = 0.5)]
    pub h: f32,
    /// Grid spacing (world units).
    #[arg(long, default_value_t = 0.125)]
    pub res: f32,
    /// preserving (Shepard: values come back at the particles) or sph (the thesis's: values shrink).
    #[arg(long, default_value = "preserving")]
    pub mode: Mode,
    /// Neighbour search: window (default, faster) or kdtree.
    #[arg(long, default_value = "window")]
    pub search: Search,
    /// Round width and height up to a multiple of this (128 for the U-Net; 1 = no padding).
    #[arg(long, default_value_t = 1)]
    pub pad_to: usize,
    /// Grid rectangle: `auto` (inner faces of the scene's walls) or `x0,y0,x1,y1`.
    #[arg(long, default_value = "auto", value_parser = parse_bounds)]
    pub bounds: BoundsArg,
    /// Append a `weight` channel (summed kernel weight; 0 where no particle reaches).
    #[arg(long)]
    pub weight_channel: bool,
}

impl GridArgs {
    /// Checks every parameter before the node starts: the kernel radius, the spacing, the padding
    /// and the grid they make over the bounds (auto bounds: over the thesis box, the walls of every
    /// scene generator; the walls of the actual scene are checked again per simulation).
    pub fn validate(&self) -> Result<(), sph::SphError> {
        sph::Kernel::new(self.kernel, self.h)?;
        let bounds = match self.bounds {
            BoundsArg::Fixed(b) => b,
            BoundsArg::Auto => Bounds::THESIS_BOX,
        };
        GridGeometry::from_bounds(bounds, self.res, self.pad_to)?;
        if self.h < 0.5 * self.res {
            return Err(sph::SphError::BadParameter(format!(
                "kernel radius h {} is below half the grid spacing {}: particles between nodes would reach none",
                self.h, self.res
            )));
        }
        Ok(())
    }

    /// The transfer configuration these arguments describe.
    pub fn transfer_config(&self) -> TransferConfig {
        TransferConfig {
            kernel: self.kernel,
            h: self.h,
            mode: self.mode,
            search: self.search,
            weight_channel: self.weight_channel,
        }
    }
}

/// Subcommands.
#[derive(clap::Subcommand, Debug)]
pub enum Command {
    /// Times the scatter of 7 channels at 100, 1,000 and 10,000 particles, k-d tree vs index window.
    Bench(BenchArgs),
}

/// Parameters of the benchmark.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// Particle counts.
    #[arg(long, value_delimiter = ',', default_value = "100,1000,10000")]
    n: Vec<usize>,
    /// Kernel, radius, spacing and mode as for the node (grid 0,0,15,15).
    #[command(flatten)]
    grid: GridArgs,
    /// Least wall time per measurement, seconds.
    #[arg(long, default_value_t = 0.3)]
    min_time_s: f64,
    /// Threads of the index-window scatter (0: every available core; it uses one per 2,000
    /// particles at most).
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

/// Runs a subcommand.
pub fn run(command: Command) -> Result<()> {
    match command {
        Command::Bench(a) => run_bench(a),
    }
}

fn run_bench(args: BenchArgs) -> Result<()> {
    let geometry = GridGeometry::from_bounds(Bounds::THESIS_BOX, args.grid.res, args.grid.pad_to)?;
    let channels = ["vx", "vy", "omega", "mass", "inertia", "prev_normal", "prev_tangent"];
    let base = args.grid.transfer_config();
    let build = Instant::now();
    Transfer::new(TransferConfig { search: Search::KdTree, ..base }, geometry)?;
    println!(
        "grid {}x{}, kernel {}, h {}, mode {}, 7 channels; k-d tree of the nodes built once per geometry in {:.2} ms; window scatter on up to {} threads",
        geometry.width,
        geometry.height,
        base.kernel,
        base.h,
        base.mode,
        1e3 * build.elapsed().as_secs_f64(),
        if args.threads > 0 { args.threads } else { std::thread::available_parallelism().map_or(1, |n| n.get()) }
    );
    // Minimum and median over repeats: on a shared machine (this VM shows ~50% steal time) the
    // minimum is the run least disturbed by other tenants, the median what a node would see.
    println!("| particles | kdtree ms/frame (min / median) | window ms/frame (min / median) | speed-up (min) |\n| --- | --- | --- | --- |");
    for &n in &args.n {
        let set = synth::scattered(n as u64, n, Bounds::THESIS_BOX, &channels);
        let mut times = Vec::new();
        for search in [Search::KdTree, Search::IndexWindow] {
            let mut t = Transfer::new(TransferConfig { search, ..base }, geometry)?;
            if args.threads > 0 {
                t.set_threads(args.threads);
            }
            let mut out = vec![0.0; t.output_len(channels.len())];
            t.splat(&set, &mut out)?; // warm-up: buffers sized
            let mut samples = Vec::new();
            let start = Instant::now();
            while samples.len() < 5 || start.elapsed().as_secs_f64() < args.min_time_s {
                let s = Instant::now();
                t.splat(&set, &mut out)?;
                samples.push(s.elapsed().as_secs_f64() * 1e3);
            }
            samples.sort_by(f64::total_cmp);
            times.push((samples[0], samples[samples.len() / 2]));
        }
        let ((kmin, kmed), (wmin, wmed)) = (times[0], times[1]);
        println!("| {n} | {kmin:.3} / {kmed:.3} | {wmin:.3} / {wmed:.3} | {:.1}x |", kmin / wmin);
    }
    Ok(())
}
