//! The encoder in the loop (`--init tokenizer|scratch`): the input a training step makes is
//! the map inference makes, a step moves the encoder's weights with the heads', and a resumed
//! run continues bit for bit, the encoder and its optimiser included.

use std::path::{Path, PathBuf};

use bevworld_heads::{InputKind, InputSpec};
use bevworld_heads_train::encoder::{encode_maps, encoded_batch, load_encoder_set};
use bevworld_heads_train::trainer::EncoderInLoop;
use bevworld_heads_train::{DetectionSet, DetectorTrainer};
use bevworld_tokenizer::{EncoderArrays, FrameInputs, Tokenizer, TokenizerConfig};
use bevworld_training::Trainee;
use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;

use crate::data::{config, synthetic_set, train_config};

fn tokenizer_config() -> TokenizerConfig {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../configs/models/tokenizer-tiny.yaml");
    TokenizerConfig::from_yaml_file(&path).expect("the tiny tokenizer's config")
}

struct Fixture {
    set: DetectionSet,
    arrays: Vec<EncoderArrays>,
    tokenizer_config: TokenizerConfig,
}

fn fixture(dir: &Path) -> Fixture {
    let data = dir.join("set");
    synthetic_set(&data);
    let tokenizer_config = tokenizer_config();
    let inputs = FrameInputs::new(&tokenizer_config);
    let (mut set, arrays) = load_encoder_set(
        &data,
        &config(),
        &inputs,
        InputKind::Feature,
        &tokenizer_config.name,
        "untrained",
    )
    .expect("the set and its encoder inputs");
    let initial = tokenizer_config.init_seeded(7, &Device::flex());
    encode_maps(
        &initial,
        InputKind::Feature,
        &mut set,
        &arrays,
        &Device::flex(),
    )
    .expect("maps");
    Fixture {
        set,
        arrays,
        tokenizer_config,
    }
}

fn spec(set: &DetectionSet, frames: usize) -> InputSpec {
    let (mean, std) = set.channel_statistics();
    InputSpec {
        kind: InputKind::Feature,
        channels: set.channels,
        grid: set.grid,
        frames,
        model: set.model.clone(),
        weights_hash: set.weights_hash.clone(),
        mean,
        std,
    }
}

fn values<M: Module>(module: &M) -> Vec<f32> {
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0
                .extend(param.val().into_data().try_to_vec::<f32>().expect("f32"));
        }
    }
    let mut collect = Collect(Vec::new());
    module.visit(&mut collect);
    collect.0
}

#[test]
fn a_training_input_is_the_map_inference_makes_standardised_and_warped() {
    let dir = tempfile::tempdir().expect("dir");
    let fixture = fixture(dir.path());
    let set = &fixture.set;
    assert_eq!(set.frames.len(), fixture.arrays.len());
    assert_eq!(set.channels, fixture.tokenizer_config.fused_channels());
    let input = spec(set, 2);
    let tokenizer: Tokenizer = fixture
        .tokenizer_config
        .init_seeded(7, &Device::flex())
        .fork(&Device::flex().autodiff())
        .train();
    // A keyframe with a previous one: its input against the one exported maps give.
    let frame = set
        .frames
        .iter()
        .position(|f| f.previous.is_some())
        .expect("a second keyframe");
    let trained = encoded_batch(
        &tokenizer,
        &input,
        &set.frames,
        &fixture.arrays,
        &[frame],
        &Device::flex().autodiff(),
    )
    .inner()
    .into_data()
    .try_to_vec::<f32>()
    .expect("f32");
    let exported =
        bevworld_heads_train::evaluate::input_batch(&input, &set.frames, &[frame], &Device::flex())
            .into_data()
            .try_to_vec::<f32>()
            .expect("f32");
    assert_eq!(trained.len(), exported.len());
    let worst = trained
        .iter()
        .zip(&exported)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    // The autodiff path is burn's tensors, inference our host kernels: equal within rounding
    // of standardised values of order 1.
    assert!(worst < 1e-3, "largest difference {worst}");
}

fn trainer(dir: &Path, fixture: &Fixture, threads: usize) -> DetectorTrainer {
    let autodiff = Device::flex().autodiff();
    let train = train_config(dir, 2, 1);
    let encoder = EncoderInLoop::new(
        fixture.tokenizer_config.clone(),
        fixture
            .tokenizer_config
            .init_seeded(7, &Device::flex())
            .fork(&autodiff)
            .train(),
        train.optimizer.adamw(),
        0.5,
        fixture.arrays.clone(),
        fixture.arrays.clone(),
    );
    DetectorTrainer::new(
        train,
        config(),
        spec(&fixture.set, 2),
        fixture.set.clone(),
        fixture.set.clone(),
        &autodiff,
        threads,
    )
    .expect("a trainer")
    .with_encoder(encoder)
}

fn encoder_values(trainer: &DetectorTrainer) -> Vec<f32> {
    values(&trainer.shipped_encoder().expect("an encoder in the loop"))
}

#[test]
fn steps_move_the_encoder_and_a_resumed_run_continues_bit_for_bit() {
    let dir = tempfile::tempdir().expect("dir");
    let fixture = fixture(dir.path());
    let mut straight = trainer(dir.path(), &fixture, 2);
    let initial = encoder_values(&straight);
    for _ in 0..2 {
        straight.train_step().expect("step");
    }
    let run = dir.path().join("run");
    straight.save_checkpoint(&run).expect("checkpoint");
    let after_two = encoder_values(&straight);
    let moved = initial
        .iter()
        .zip(&after_two)
        .filter(|(a, b)| a != b)
        .count();
    // The fusion, the backbones and the compression all learn; the decoder, which the
    // detector never reads, keeps its weights.
    assert!(
        moved > initial.len() / 20,
        "{moved} of {} encoder weights moved",
        initial.len()
    );
    assert!(
        moved < initial.len(),
        "the decoder has no gradient, so it does not move"
    );
    for _ in 0..2 {
        straight.train_step().expect("step");
    }

    let mut resumed = trainer(dir.path(), &fixture, 1)
        .resume(&run)
        .expect("resume");
    assert_eq!(resumed.step(), 2);
    assert_eq!(encoder_values(&resumed), after_two);
    for _ in 0..2 {
        resumed.train_step().expect("step");
    }
    assert_eq!(encoder_values(&resumed), encoder_values(&straight));
    assert_eq!(
        values(&resumed.shipped_model()),
        values(&straight.shipped_model())
    );
}
