//! The `study` and `bench` subcommands and the grid parameters shared with the node.

use crate::heatmap::write_heatmap;
use anyhow::{bail, Context, Result};
use sph::study::{self, StudyCase, StudyFrame};
use sph::{synth, Bounds, GridGeometry, KernelKind, Mode, ParticleSet, Search, Transfer, TransferConfig};
use std::path::{Path, PathBuf};
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
    /// Transfer-error study: particle -> grid -> particle over kernel x h x res x mode.
    Study(StudyArgs),
    /// Times the scatter of 7 channels at 100, 1,000 and 10,000 particles, k-d tree vs index window.
    Bench(BenchArgs),
}

/// Parameters of the study.
#[derive(clap::Args, Debug)]
pub struct StudyArgs {
    /// Frames: `pile` (100-ball piles, contacts), `scattered` (uniform particles, smooth values),
    /// `isolated` (particles > 1.1 apart), `csv:PATH` (contacts, columns frame,x,y,normal,tangent),
    /// or `mcap:PATH` (the contacts of a recording's steps, a file or a folder: real sim frames).
    #[arg(long, default_value = "pile")]
    dataset: String,
    /// Synthetic frames (seeds 0..N); for `mcap:` at most N steps with contacts, evenly spread.
    #[arg(long, default_value_t = 8)]
    frames: u64,
    /// Kernels to try.
    #[arg(long, value_delimiter = ',', default_value = "poly6,spiky,gaussian")]
    kernels: Vec<KernelKind>,
    /// Support radii to try.
    #[arg(long, value_delimiter = ',', default_value = "0.25,0.5,0.75,1.0")]
    hs: Vec<f32>,
    /// Grid spacings to try.
    #[arg(long, value_delimiter = ',', default_value = "0.0625,0.125,0.25")]
    ress: Vec<f32>,
    /// Modes to try.
    #[arg(long, value_delimiter = ',', default_value = "sph,preserving")]
    modes: Vec<Mode>,
    /// Grid rectangle `x0,y0,x1,y1` (default: the walls' inner faces for `mcap:`, else 0,0,15,15).
    #[arg(long)]
    bounds: Option<Bounds>,
    /// Output folder for study.csv, study.md and the heat-maps.
    #[arg(long, default_value = "sph-study")]
    out: PathBuf,
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
        Command::Study(a) => run_study(a),
        Command::Bench(a) => run_bench(a),
    }
}

/// Frames of a recording: the contacts of up to `max` of its steps that have contacts, evenly
/// spread over the recording, and the grid rectangle of its first step's walls.
fn recorded_frames(path: &Path, max: u64) -> Result<(Vec<StudyFrame>, Option<Bounds>)> {
    let mut steps = recorder::Steps::open(path)?;
    let mut all = Vec::new();
    let mut walls = None;
    for step in steps.by_ref() {
        let step = step?;
        if walls.is_none() {
            walls = Bounds::from_walls(&step.bodies.items);
        }
        if !step.contacts.items.is_empty() {
            let k = step.key;
            let name = format!("run{}-sim{}-step{}", k.run_id, k.simulation, k.step);
            all.push(study::contacts_frame(name, &step.contacts.items)?);
        }
    }
    if steps.incomplete() + steps.undecodable() > 0 {
        tracing::warn!(incomplete = steps.incomplete(), undecodable = steps.undecodable(), "steps skipped");
    }
    let max = max.max(1) as usize;
    if all.len() > max {
        // Evenly spread, first and last included.
        let last = all.len() - 1;
        let picks: Vec<usize> = (0..max).map(|k| (k * last + (max - 1) / 2) / (max - 1).max(1)).collect();
        all = picks.into_iter().map(|i| all[i].clone()).collect();
    }
    Ok((all, walls))
}

fn study_frames(args: &StudyArgs) -> Result<(Vec<StudyFrame>, Option<Bounds>)> {
    let frame = |name: String, particles: ParticleSet| StudyFrame { name, particles };
    let bounds = args.bounds.unwrap_or(Bounds::THESIS_BOX);
    if let Some(path) = args.dataset.strip_prefix("mcap:") {
        return recorded_frames(Path::new(path), args.frames);
    }
    let frames = match args.dataset.as_str() {
        "pile" => (0..args.frames)
            .map(|s| Ok(frame(format!("pile-{s}"), ParticleSet::from_contacts(&synth::ball_pile(s, 100).contacts)?)))
            .collect::<Result<_>>()?,
        "scattered" => (0..args.frames)
            .map(|s| frame(format!("scattered-{s}"), synth::scattered(s, 300, bounds, &sph::CONTACT_CHANNELS)))
            .collect(),
        "isolated" => {
            (0..args.frames).map(|s| frame(format!("isolated-{s}"), synth::isolated(s, 40, bounds, 1.1))).collect()
        }
        other => match other.strip_prefix("csv:") {
            Some(path) => {
                let text = std::fs::read_to_string(path).with_context(|| format!("reading {path}"))?;
                study::frames_from_contacts_csv(path, &text)?
            }
            None => bail!("unknown dataset `{other}` (pile, scattered, isolated, csv:PATH, mcap:PATH)"),
        },
    };
    Ok((frames, None))
}

fn run_study(args: StudyArgs) -> Result<()> {
    let (frames, walls) = study_frames(&args)?;
    if frames.is_empty() {
        bail!("dataset `{}` has no frames", args.dataset);
    }
    let bounds = args.bounds.or(walls).unwrap_or(Bounds::THESIS_BOX);
    eprintln!("grid rectangle {bounds:?}");
    let cases = study::cases(&args.kernels, &args.hs, &args.ress, &args.modes);
    eprintln!("{} cases x {} frames ({})", cases.len(), frames.len(), args.dataset);
    let results = cases.iter().map(|&c| study::run_case(c, &frames, bounds)).collect::<Result<Vec<_>, _>>()?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    std::fs::write(args.out.join("study.csv"), study::to_csv(&results))?;
    let mut md = format!("# SPH transfer-error study: {} ({} frames)\n\n", args.dataset, frames.len());
    md += &highlights(&results);
    md += "\n## All cases\n\n";
    md += &study::to_markdown(&results);
    std::fs::write(args.out.join("study.md"), &md)?;
    print!("{}", highlights(&results));

    // Heat-maps of the first frame's first channel at the thesis's parameters, both modes.
    let geometry = GridGeometry::from_bounds(bounds, 0.125, 1)?;
    for mode in Mode::ALL {
        let config = TransferConfig { mode, ..TransferConfig::default() };
        let mut t = Transfer::new(config, geometry)?;
        let set = &frames[0].particles;
        let mut grid = vec![0.0; t.output_len(set.channel_count())];
        t.splat(set, &mut grid)?;
        let path = args.out.join(format!("heatmap-{}-{mode}.png", frames[0].name.replace(['/', '#', ':'], "_")));
        write_heatmap(&path, &geometry, &grid[..geometry.nodes()], set.positions(), 4)?;
        eprintln!("wrote {}", path.display());
    }
    eprintln!("wrote {}/study.csv and study.md", args.out.display());
    Ok(())
}

/// The thesis's case in both modes, and the best case of each mode by relative error.
fn highlights(results: &[study::CaseResult]) -> String {
    let mut picked: Vec<(&str, &study::CaseResult)> = Vec::new();
    let thesis = |m| StudyCase { kernel: KernelKind::Poly6, h: 0.5, res: 0.125, mode: m };
    for mode in Mode::ALL {
        if let Some(r) = results.iter().find(|r| r.case == thesis(mode)) {
            picked.push(("thesis parameters", r));
        }
        let best = results
            .iter()
            .filter(|r| r.case.mode == mode && r.rel_error.is_finite())
            .min_by(|a, b| a.rel_error.total_cmp(&b.rel_error));
        if let Some(r) = best {
            picked.push(("lowest rel. error", r));
        }
    }
    let mut s = String::from("## Highlights\n\n| which | kernel | h | res | mode | MSE | rel. error | scale bias | us / frame |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
    for (which, r) in picked {
        let c = r.case;
        s += &format!(
            "| {which} | {} | {} | {} | {} | {:.3e} | {:.3} | {:.3} | {:.0} |\n",
            c.kernel, c.h, c.res, c.mode, r.mse, r.rel_error, r.scale_bias, r.us_per_frame
        );
    }
    s
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
