//! Progress of a bake's stage units: a terminal view (one line per running unit with its counts
//! and an ETA), newline-delimited JSON events for CI logs, or nothing.

use super::StageRecord;
use serde_json::json;
use std::collections::HashMap;
use std::io::Write;
use std::sync::Mutex;
use std::time::Instant;

/// Receives the events of a bake. Implementations must be cheap: `progress` is called from
/// the stages' worker threads.
pub trait Observer: Sync {
    /// A unit starts; `total` is its work count (vertices, instances) where known.
    fn start(&self, _stage: &str, _unit: &str, _total: Option<u64>) {}
    /// `n` more of the unit's work is done.
    fn progress(&self, _stage: &str, _unit: &str, _n: u64) {}
    /// A unit ended (computed or taken from the cache).
    fn end(&self, _record: &StageRecord) {}
}

/// No progress at all (`--quiet`, library callers).
pub struct Silent;
impl Observer for Silent {}

/// indicatif bars on stderr: one line per running unit
/// (`prt tree003.txf [====>   ] 12,340/40,000 vertices 0:42 eta 0:31`), a finished unit leaves
/// a line with its time and cache status.
pub struct Terminal {
    multi: indicatif::MultiProgress,
    bars: Mutex<HashMap<(String, String), indicatif::ProgressBar>>,
}

impl Default for Terminal {
    fn default() -> Self {
        Terminal {
            multi: indicatif::MultiProgress::with_draw_target(
                indicatif::ProgressDrawTarget::stderr(),
            ),
            bars: Mutex::new(HashMap::new()),
        }
    }
}

fn what(stage: &str) -> &'static str {
    match stage {
        "prt" => "vertices",
        "envmaps" => "instances",
        _ => "",
    }
}

impl Observer for Terminal {
    fn start(&self, stage: &str, unit: &str, total: Option<u64>) {
        let bar = match total {
            Some(t) => {
                let b = indicatif::ProgressBar::new(t);
                let tpl = format!(
                    "{{prefix:>10}} {{msg:24}} [{{bar:24}}] {{human_pos}}/{{human_len}} {} {{elapsed}} eta {{eta}}",
                    what(stage)
                );
                b.set_style(
                    indicatif::ProgressStyle::with_template(&tpl)
                        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
                        .progress_chars("=> "),
                );
                b
            }
            None => {
                let b = indicatif::ProgressBar::new_spinner();
                b.set_style(
                    indicatif::ProgressStyle::with_template(
                        "{prefix:>10} {msg:24} {spinner} {elapsed}",
                    )
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
                );
                b.enable_steady_tick(std::time::Duration::from_millis(200));
                b
            }
        };
        bar.set_prefix(stage.to_string());
        bar.set_message(unit.to_string());
        let bar = self.multi.add(bar);
        if let Ok(mut m) = self.bars.lock() {
            m.insert((stage.to_string(), unit.to_string()), bar);
        }
    }

    fn progress(&self, stage: &str, unit: &str, n: u64) {
        if let Ok(m) = self.bars.lock()
            && let Some(b) = m.get(&(stage.to_string(), unit.to_string()))
        {
            b.inc(n);
        }
    }

    fn end(&self, r: &StageRecord) {
        let bar = self
            .bars
            .lock()
            .ok()
            .and_then(|mut m| m.remove(&(r.stage.clone(), r.unit.clone())));
        let line = format!(
            "{:24} {:>8.2} s {:>8.2} CPU s  {}",
            r.unit, r.wall_seconds, r.cpu_seconds, r.cache
        );
        match bar {
            // The unit's own line becomes its summary.
            Some(b) => {
                b.set_style(
                    indicatif::ProgressStyle::with_template("{prefix:>10} {msg}")
                        .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
                );
                b.finish_with_message(line);
            }
            None => {
                let _ = self.multi.println(format!("{:>10} {line}", r.stage));
            }
        }
    }
}

/// One JSON object per line on stderr (`--progress ndjson`): `{"event": "start"|"progress"|
/// "end", "stage", "unit", "t"}` plus `total`, `done`, or the record's timings, cache status and
/// outputs. Progress events are throttled to at most ten per second per unit.
pub struct Ndjson {
    t0: Instant,
    state: Mutex<HashMap<(String, String), (u64, f64)>>,
}

impl Default for Ndjson {
    fn default() -> Self {
        Ndjson {
            t0: Instant::now(),
            state: Mutex::new(HashMap::new()),
        }
    }
}

impl Ndjson {
    fn emit(&self, v: serde_json::Value) {
        let mut err = std::io::stderr().lock();
        let _ = writeln!(err, "{v}");
    }
}

impl Observer for Ndjson {
    fn start(&self, stage: &str, unit: &str, total: Option<u64>) {
        if let Ok(mut s) = self.state.lock() {
            s.insert((stage.into(), unit.into()), (0, 0.0));
        }
        self.emit(json!({"event": "start", "stage": stage, "unit": unit, "total": total, "t": self.t0.elapsed().as_secs_f64()}));
    }

    fn progress(&self, stage: &str, unit: &str, n: u64) {
        let t = self.t0.elapsed().as_secs_f64();
        let due = self.state.lock().ok().and_then(|mut s| {
            let e = s.entry((stage.into(), unit.into())).or_insert((0, 0.0));
            e.0 += n;
            if t - e.1 >= 0.1 {
                e.1 = t;
                Some(e.0)
            } else {
                None
            }
        });
        if let Some(done) = due {
            self.emit(
                json!({"event": "progress", "stage": stage, "unit": unit, "done": done, "t": t}),
            );
        }
    }

    fn end(&self, r: &StageRecord) {
        self.emit(json!({
            "event": "end",
            "stage": r.stage,
            "unit": r.unit,
            "cache": r.cache,
            "wall_seconds": r.wall_seconds,
            "cpu_seconds": r.cpu_seconds,
            "outputs": r.outputs,
            "t": self.t0.elapsed().as_secs_f64(),
        }));
    }
}
