//! `dc-sph-study`: the transfer-error study, particle -> grid -> particle over kernel x h x res x
//! mode, on synthetic frames or a recording's contacts. Writes `study.csv`, `study.md` and two
//! heat-maps of the first frame (thesis parameters, both modes) to `--out`, and prints the
//! highlights. The finding it backs: the thesis's normalisation (`sph` mode) brings back under a
//! fifth of an impulse, the `preserving` mode the product uses keeps its scale.

mod heatmap;

use anyhow::{bail, Context, Result};
use clap::Parser;
use experiments::sph_study::{self as study, StudyCase, StudyFrame};
use heatmap::write_heatmap;
use sph::{synth, Bounds, GridGeometry, KernelKind, Mode, ParticleSet, Transfer, TransferConfig};
use std::path::{Path, PathBuf};

/// Parameters of the study.
#[derive(Parser, Debug)]
#[command(
    name = "dc-sph-study",
    about = "Transfer-error study: particle -> grid -> particle over kernel x h x res x mode"
)]
struct StudyArgs {
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

fn main() -> std::process::ExitCode {
    let args = StudyArgs::parse();
    runtime::init_logging();
    runtime::exit(run_study(args))
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
