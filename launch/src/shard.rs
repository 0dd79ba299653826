//! `dc launch FILE --shard I/N`: a launch file's graph as one shard of its seeds. What a shard's
//! manifest records, and its life, are [`runtime::shard`]'s.

use anyhow::Result;
use msgs::shard::Shard;
use std::path::Path;

/// `dc launch FILE --shard I/N`: the graph made to run the I-th of N parts of its seeds, so one
/// launch file (a recording graph, say) is an array job's task, on one host or several (every host
/// of a shard runs the file with the same `--shard` and computes the same graph). Each node's
/// `seeds` becomes its part; each recorder writes apart from the other shards (`--out x.mcap`:
/// `x.shard-I-of-N.mcap`; its `--dir`, given or default, gains `shard-I-of-N/`); the namespace
/// gains `-shard-I`, so shards sharing a host or a zenoh network never meet. Returns a line per
/// change, for the log.
pub fn shard_graph(graph: &mut crate::graph::Graph, shard: Shard) -> Result<Vec<String>> {
    let mut changes = Vec::new();
    let tag = format!("shard-{}-of-{}", shard.index, shard.count);
    for node in &mut graph.nodes {
        for arg in &mut node.args {
            if let Some(list) = arg.strip_prefix("--seeds=") {
                let seeds = msgs::parse_seeds(list)
                    .map_err(|e| anyhow::anyhow!("{}: node `{}`: seeds `{list}`: {e}", graph.file, node.name))?;
                let part = shard
                    .seeds(&seeds)
                    .map_err(|e| anyhow::anyhow!("--shard {shard}: node `{}` ({list}): {e}", node.name))?;
                let part = msgs::shard::format_seeds(&part);
                changes.push(format!("{}: seeds {list} -> {part}", node.name));
                *arg = format!("--seeds={part}");
            }
        }
        if node.binary == "dc-record" {
            let mut has_out = false;
            for arg in &mut node.args {
                if let Some(out) = arg.strip_prefix("--out=") {
                    let path = Path::new(out);
                    let stem = path.file_stem().map_or_else(|| out.to_string(), |s| s.to_string_lossy().into_owned());
                    let ext = path.extension().map_or_else(String::new, |e| format!(".{}", e.to_string_lossy()));
                    let moved = path.with_file_name(format!("{stem}.{tag}{ext}")).display().to_string();
                    changes.push(format!("{}: out {out} -> {moved}", node.name));
                    *arg = format!("--out={moved}");
                    has_out = true;
                }
            }
            if !has_out {
                let dir_at = node.args.iter().position(|a| a.starts_with("--dir="));
                let dir = dir_at.map_or("recordings".to_string(), |i| node.args[i]["--dir=".len()..].to_string());
                let moved = Path::new(&dir).join(&tag).display().to_string();
                changes.push(format!("{}: dir {dir} -> {moved}", node.name));
                match dir_at {
                    Some(i) => node.args[i] = format!("--dir={moved}"),
                    None => node.args.push(format!("--dir={moved}")),
                }
            }
        }
    }
    if !changes.iter().any(|c| c.contains(": seeds ")) {
        anyhow::bail!(
            "--shard {shard}: no node of {} has a `seeds` parameter: nothing to split (give the simulators `seeds = \"0..30\"`)",
            graph.file
        );
    }
    let namespace = format!("{}-shard-{}", graph.namespace, shard.index);
    runtime::check_namespace(&namespace)
        .map_err(|why| anyhow::anyhow!("--shard {shard}: namespace `{namespace}`: {why}"))?;
    changes.push(format!("namespace {} -> {namespace}", graph.namespace));
    graph.namespace = namespace;
    Ok(changes)
}
