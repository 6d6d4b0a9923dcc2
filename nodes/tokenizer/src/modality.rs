//! The sensors a tokenizer reads and is trained to render. The paper's modality ablation trains
//! three tokenizers: cameras only (C→C), LiDAR only (L→L), and both (L&C→L&C, the default).

use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Modality {
    Camera,
    Lidar,
}

impl Modality {
    pub const BOTH: [Modality; 2] = [Modality::Camera, Modality::Lidar];

    /// `camera`, `lidar`, or both joined by a comma (`camera,lidar`), as the CLI takes them.
    pub fn parse_list(text: &str) -> Result<Vec<Modality>, String> {
        let mut list = Vec::new();
        for word in text.split(',').map(str::trim) {
            let modality = match word {
                "camera" => Modality::Camera,
                "lidar" => Modality::Lidar,
                other => {
                    return Err(format!(
                        "unknown modality '{other}': expected camera, lidar or camera,lidar"
                    ));
                }
            };
            if list.contains(&modality) {
                return Err(format!("modality '{word}' is named twice"));
            }
            list.push(modality);
        }
        Ok(list)
    }

    /// The word the configs and the CLI use: `camera` or `lidar`.
    pub fn name(self) -> &'static str {
        match self {
            Modality::Camera => "camera",
            Modality::Lidar => "lidar",
        }
    }

    /// What a model renders of it, for messages: `cameras` or `LiDAR`.
    pub fn plural(self) -> &'static str {
        match self {
            Modality::Camera => "cameras",
            Modality::Lidar => "LiDAR",
        }
    }

    /// The paper's notation: `C`, `L`, or `L&C`.
    pub fn paper_name(list: &[Modality]) -> &'static str {
        match (
            list.contains(&Modality::Camera),
            list.contains(&Modality::Lidar),
        ) {
            (true, true) => "L&C",
            (true, false) => "C",
            (false, true) => "L",
            (false, false) => "none",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_cli_forms_and_refuses_the_rest() {
        assert_eq!(Modality::parse_list("camera"), Ok(vec![Modality::Camera]));
        assert_eq!(
            Modality::parse_list("lidar, camera"),
            Ok(vec![Modality::Lidar, Modality::Camera])
        );
        assert!(Modality::parse_list("radar").is_err_and(|e| e.contains("radar")));
        assert!(Modality::parse_list("lidar,lidar").is_err_and(|e| e.contains("twice")));
        assert!(Modality::parse_list("").is_err());
        assert_eq!(Modality::paper_name(&Modality::BOTH), "L&C");
        assert_eq!(Modality::paper_name(&[Modality::Lidar]), "L");
    }
}
