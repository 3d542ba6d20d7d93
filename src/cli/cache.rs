//! `bake cache stats|gc`: the stage cache's size, and trimming it.

use super::{Global, Outcome};
use crate::error::{Error, Result};
use crate::graph::cache::{Cache, default_dir};
use std::path::PathBuf;

#[derive(Debug, Clone, clap::Args)]
pub(crate) struct CacheArgs {
    #[command(subcommand)]
    pub action: CacheAction,
    /// The cache folder (default: as `bake build` picks it).
    #[arg(long, global = true, value_name = "DIR")]
    pub dir: Option<PathBuf>,
}

#[derive(Debug, Clone, clap::Subcommand)]
pub(crate) enum CacheAction {
    /// Entries, bytes and stale temporary files.
    Stats,
    /// Remove stale temporary files and the least recently used entries above a size.
    Gc {
        /// Keep at most this much, e.g. 500M, 20G, 1.5T (bytes without a suffix).
        #[arg(long, value_name = "SIZE", value_parser = parse_size)]
        max_size: u64,
    },
}

/// Parses `123`, `500K`, `20M`, `1.5G`, `2T` (powers of 1024).
pub(crate) fn parse_size(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    let (num, mul) = match t.char_indices().last() {
        Some((i, c)) if c.is_ascii_alphabetic() => {
            let m = match c.to_ascii_uppercase() {
                'K' => 1u64 << 10,
                'M' => 1 << 20,
                'G' => 1 << 30,
                'T' => 1 << 40,
                'B' => 1,
                _ => return Err(format!("{s:?}: unknown size suffix {c:?} (K, M, G, T)")),
            };
            (&t[..i], m)
        }
        _ => (t, 1),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a size such as 500M or 20G"))?;
    if !v.is_finite() || v < 0.0 {
        return Err(format!("{s:?} is not a size"));
    }
    Ok((v * mul as f64) as u64)
}

pub(crate) fn run(args: &CacheArgs, _g: &Global) -> Result<Outcome> {
    let dir = args
        .dir
        .clone()
        .unwrap_or_else(|| default_dir(std::path::Path::new("out.bake")));
    if !dir.exists() {
        return Err(Error::usage(format!("no cache at {}", dir.display())));
    }
    let cache = Cache::new(&dir);
    let before = cache.stats();
    let (stats, verb) = match &args.action {
        CacheAction::Stats => (before.clone(), "holds"),
        CacheAction::Gc { max_size } => (cache.gc(*max_size), "now holds"),
    };
    let mut json = serde_json::to_value(&stats).unwrap_or_default();
    json["removed_entries"] = serde_json::json!(before.entries - stats.entries.min(before.entries));
    Ok(Outcome {
        text: format!(
            "{} {verb} {} entries, {} bytes ({} stale temporary files)\n",
            dir.display(),
            stats.entries,
            stats.bytes,
            stats.stale_temporaries
        ),
        json,
        warnings: Vec::new(),
    })
}
