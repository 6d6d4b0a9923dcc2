//! The tables of action-control runs, from their JSON (`bevworld eval control --json`): per
//! manoeuvre, each run's pairs right and swap ratio side by side, the accuracy over all with
//! its spread over the branched scenes, and every pair a run got wrong with the truth its
//! forecast fell nearest. The pages quote these, generated from the figures, never typed.
//!
//!   cargo run --release -p bevworld-bench --bin control_tables -- shipped=a.json "fine-tune=b.json"
//!
//! A pair (scene, manoeuvre a) is right when a's forecast is strictly closer to a's truth than
//! to every other branch's, the rule of `eval control`; the accuracies are recounted here from
//! the distance matrices, and a file whose recount differs from its own `accuracy` is refused.

use std::collections::BTreeMap;
use std::fmt::Write as _;

const USAGE: &str = "usage: control_tables LABEL=CONTROL.json ...";

/// One forecast (scene, manoeuvre): its distance to its own truth and to every other one.
#[derive(Clone, Debug, PartialEq)]
struct Pair {
    scene: String,
    manoeuvre: String,
    own: f64,
    others: Vec<(String, f64)>,
}

impl Pair {
    fn right(&self) -> bool {
        self.others.iter().all(|(_, d)| *d > self.own)
    }

    /// The other truth this forecast lies nearest, and its distance.
    fn nearest_other(&self) -> Option<&(String, f64)> {
        self.others.iter().min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// `eval control`'s swap ratios: each other truth's distance over the own one's.
    fn swap_ratios(&self) -> impl Iterator<Item = f64> + '_ {
        self.others
            .iter()
            .filter(|_| self.own > 0.0)
            .map(|(_, d)| d / self.own)
    }
}

/// A run's pairs in scene order, and its reported accuracy.
struct Run {
    label: String,
    pairs: Vec<Pair>,
}

fn pairs_of(file: &str, json: &serde_json::Value) -> Result<Vec<Pair>, String> {
    let scenes = json["distances"]
        .as_object()
        .ok_or_else(|| format!("{file}: no \"distances\" object"))?;
    let mut pairs = Vec::new();
    for (scene, matrix) in scenes {
        let matrix = matrix
            .as_object()
            .ok_or_else(|| format!("{file}: distances.{scene} is not an object"))?;
        for (manoeuvre, row) in matrix {
            let row = row
                .as_object()
                .ok_or_else(|| format!("{file}: distances.{scene}.{manoeuvre} is not an object"))?;
            let distance = |truth: &str| {
                row[truth].as_f64().ok_or_else(|| {
                    format!("{file}: distances.{scene}.{manoeuvre}.{truth} is not a number")
                })
            };
            let own = distance(manoeuvre)?;
            let others = row
                .keys()
                .filter(|t| *t != manoeuvre)
                .map(|t| Ok((t.clone(), distance(t)?)))
                .collect::<Result<_, String>>()?;
            pairs.push(Pair {
                scene: scene.clone(),
                manoeuvre: manoeuvre.clone(),
                own,
                others,
            });
        }
    }
    if pairs.is_empty() {
        return Err(format!("{file}: no pairs"));
    }
    let right = pairs.iter().filter(|p| p.right()).count();
    let reported = json["accuracy"]
        .as_f64()
        .ok_or_else(|| format!("{file}: no \"accuracy\" number"))?;
    let recounted = right as f64 / pairs.len() as f64;
    if (recounted - reported).abs() > 1e-9 {
        return Err(format!(
            "{file}: its distances give {right} of {} pairs right, its accuracy says {reported}",
            pairs.len()
        ));
    }
    Ok(pairs)
}

/// Mean and population spread of each scene's accuracy.
fn scene_spread(pairs: &[Pair]) -> (f64, f64) {
    let mut by_scene: BTreeMap<&str, (usize, usize)> = BTreeMap::new();
    for pair in pairs {
        let entry = by_scene.entry(&pair.scene).or_default();
        entry.0 += usize::from(pair.right());
        entry.1 += 1;
    }
    let shares: Vec<f64> = by_scene
        .values()
        .map(|(right, all)| *right as f64 / *all as f64)
        .collect();
    let mean = shares.iter().sum::<f64>() / shares.len() as f64;
    let variance = shares.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / shares.len() as f64;
    (mean, variance.sqrt())
}

/// The manoeuvres in the order `eval control` reports them (their enum order).
fn manoeuvre_order(name: &str) -> usize {
    bevworld_types::Manoeuvre::parse(name)
        .and_then(|m| bevworld_types::Manoeuvre::ALL.iter().position(|x| *x == m))
        .unwrap_or(usize::MAX)
}

fn markdown(runs: &[Run]) -> String {
    let mut names: Vec<&str> = runs
        .iter()
        .flat_map(|r| r.pairs.iter().map(|p| p.manoeuvre.as_str()))
        .collect();
    names.sort_by_key(|n| (manoeuvre_order(n), n.to_string()));
    names.dedup();
    let mut out = String::new();
    let _ = write!(out, "| manoeuvre |");
    for run in runs {
        let _ = write!(out, " {}: right | {}: swap ratio |", run.label, run.label);
    }
    let _ = write!(out, "\n|---|");
    for _ in runs {
        let _ = write!(out, "---|---|");
    }
    out.push('\n');
    for name in &names {
        let _ = write!(out, "| {name} |");
        for run in runs {
            let of: Vec<&Pair> = run.pairs.iter().filter(|p| p.manoeuvre == *name).collect();
            let right = of.iter().filter(|p| p.right()).count();
            let ratios: Vec<f64> = of.iter().flat_map(|p| p.swap_ratios()).collect();
            let _ = write!(out, " {right} / {} |", of.len());
            if ratios.is_empty() {
                let _ = write!(out, " — |");
            } else {
                let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
                let _ = write!(out, " {mean:.2} |");
            }
        }
        out.push('\n');
    }
    let _ = write!(out, "| **all** |");
    for run in runs {
        let right = run.pairs.iter().filter(|p| p.right()).count();
        let (mean, spread) = scene_spread(&run.pairs);
        let _ = write!(
            out,
            " **{right} / {} ({:.0}%)**, scenes {:.0} ± {:.0}% | |",
            run.pairs.len(),
            100.0 * right as f64 / run.pairs.len() as f64,
            100.0 * mean,
            100.0 * spread
        );
    }
    out.push('\n');
    let wrong: Vec<(&str, &Pair)> = runs
        .iter()
        .flat_map(|r| {
            r.pairs
                .iter()
                .filter(|p| !p.right())
                .map(|p| (r.label.as_str(), p))
        })
        .collect();
    if !wrong.is_empty() {
        out.push_str("\n| run | scene | forecast | nearest truth | Chamfer to its own / to that truth (m²) |\n|---|---|---|---|---|\n");
        for (label, pair) in wrong {
            if let Some((truth, d)) = pair.nearest_other() {
                let _ = writeln!(
                    out,
                    "| {label} | {} | {} | {truth} | {:.2} / {d:.2} |",
                    pair.scene, pair.manoeuvre, pair.own
                );
            }
        }
    }
    out
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.is_empty() {
        eprintln!("{USAGE}");
        std::process::exit(2);
    }
    let mut runs = Vec::new();
    for arg in &args {
        let Some((label, path)) = arg.split_once('=') else {
            eprintln!("{arg}: not LABEL=FILE\n{USAGE}");
            std::process::exit(2);
        };
        let parsed = std::fs::read(path)
            .map_err(|e| format!("{path}: {e}"))
            .and_then(|bytes| {
                serde_json::from_slice::<serde_json::Value>(&bytes)
                    .map_err(|e| format!("{path}: {e}"))
            })
            .and_then(|json| pairs_of(path, &json));
        match parsed {
            Ok(pairs) => runs.push(Run {
                label: label.to_string(),
                pairs,
            }),
            Err(error) => {
                eprintln!("{error}");
                std::process::exit(1);
            }
        }
    }
    print!("{}", markdown(&runs));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two scenes, three branches; scene b's `right` forecast is nearer the `keep` truth.
    fn sample() -> serde_json::Value {
        serde_json::json!({
            "accuracy": 5.0 / 6.0,
            "distances": {
                "a": {
                    "keep": {"keep": 1.0, "left": 4.0, "right": 2.0},
                    "left": {"keep": 3.0, "left": 1.5, "right": 6.0},
                    "right": {"keep": 2.5, "left": 9.0, "right": 2.0}
                },
                "b": {
                    "keep": {"keep": 1.0, "left": 2.0, "right": 3.0},
                    "left": {"keep": 4.0, "left": 1.0, "right": 8.0},
                    "right": {"keep": 1.8, "left": 7.0, "right": 2.0}
                }
            }
        })
    }

    #[test]
    fn pairs_are_recounted_from_the_distances_as_eval_control_counts_them() {
        let pairs = pairs_of("x.json", &sample()).expect("pairs");
        assert_eq!(pairs.len(), 6);
        let wrong: Vec<&Pair> = pairs.iter().filter(|p| !p.right()).collect();
        assert_eq!(wrong.len(), 1);
        assert_eq!(
            (wrong[0].scene.as_str(), wrong[0].manoeuvre.as_str()),
            ("b", "right")
        );
        assert_eq!(wrong[0].nearest_other(), Some(&("keep".to_string(), 1.8)));
        // Scene a: 3 of 3, scene b: 2 of 3 → mean 5/6, spread 1/6.
        let (mean, spread) = scene_spread(&pairs);
        assert!((mean - 5.0 / 6.0).abs() < 1e-12 && (spread - 1.0 / 6.0).abs() < 1e-12);
        let table = markdown(&[Run {
            label: "m".into(),
            pairs,
        }]);
        // keep: ratios 4, 2, 2, 3 → 2.75; right: 1.25, 4.5, 0.9, 3.5 → 2.5375.
        assert!(table.contains("| keep | 2 / 2 | 2.75 |"), "{table}");
        assert!(table.contains("| right | 1 / 2 | 2.54 |"), "{table}");
        assert!(
            table.contains("**5 / 6 (83%)**, scenes 83 ± 17%"),
            "{table}"
        );
        assert!(
            table.contains("| m | b | right | keep | 2.00 / 1.80 |"),
            "{table}"
        );
    }

    #[test]
    fn a_tie_is_wrong_and_a_file_whose_accuracy_disagrees_is_refused() {
        let tie = serde_json::json!({
            "accuracy": 0.5,
            "distances": {"a": {
                "keep": {"keep": 1.0, "left": 1.0},
                "left": {"keep": 3.0, "left": 1.0}
            }}
        });
        let pairs = pairs_of("tie.json", &tie).expect("pairs");
        assert!(!pairs[0].right() && pairs[1].right());
        let mut claimed = sample();
        claimed["accuracy"] = serde_json::json!(1.0);
        let error = pairs_of("claimed.json", &claimed).expect_err("disagrees");
        assert!(
            error.contains("claimed.json") && error.contains("5 of 6"),
            "{error}"
        );
        let mut broken = sample();
        broken["distances"]["a"]["keep"]["left"] = serde_json::json!("far");
        let error = pairs_of("broken.json", &broken).expect_err("not a number");
        assert!(error.contains("distances.a.keep.left"), "{error}");
        let error = pairs_of("none.json", &serde_json::json!({})).expect_err("none");
        assert!(
            error.contains("none.json") && error.contains("distances"),
            "{error}"
        );
    }
}
