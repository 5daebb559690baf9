//! Throughput of PlumeNet, and the export that lets `scripts/torch_unet_bench.py` run the
//! identical network in PyTorch side by side (`plumenet bench-net`).
//!
//! [`export_reference`] writes the bank inputs, Burn's raw outputs, the obstacle mask and every
//! weight tensor (one `.npy` per parameter, named by its module path, which is also its PyTorch
//! `state_dict` key), so the reference loads the same weights and checks that it computes the
//! same fields before it is timed. [`forward_macs`] counts the multiply-adds of one forward pass
//! analytically, and [`cpu_peak`] estimates the machine's peak single-precision rate, so the
//! throughputs can be printed as a fraction of the peak.

use std::path::Path;
use std::time::Instant;

use burn::optim::{AdamWConfig, GradientsParams};
use burn::prelude::*;
use ndarray::{Array2, ArrayD, IxDyn};

use plumenet::error::{Error, Result};
use plumenet::frame::Frame;
use plumenet::io;
use plumenet::layout::Layout;
use plumenet::surrogate::config::TrainingConfig;
use plumenet::surrogate::conv::kernel::ConvShape;
use plumenet::surrogate::conv::{burn_conv2d_same, conv2d_same};
use plumenet::surrogate::inference::Surrogate;
use plumenet::surrogate::model::{ConvImpl, PlumeNetConfig};
use plumenet::surrogate::saved::named_tensors;
use plumenet::surrogate::training::loss;

/// Multiply-adds of one forward pass of `config` on an `[h, w]` grid (convolutions, transposed
/// convolutions and the 1x1 head; pooling, ReLU and concatenation are not counted).
pub fn forward_macs(config: &PlumeNetConfig, [h, w]: [usize; 2]) -> u64 {
    let f = &config.filters;
    let k2 = (config.kernel_size * config.kernel_size) as u64;
    let pixels = |level: usize| ((h >> level) * (w >> level)) as u64;
    let block = |level: usize, cin: usize, cout: usize| {
        let first = cin as u64 * cout as u64;
        let rest = (config.convs_per_level as u64 - 1) * (cout * cout) as u64;
        pixels(level) * k2 * (first + rest)
    };
    let mut macs = 0;
    for (l, &c) in f.iter().enumerate() {
        macs += block(l, if l == 0 { config.in_channels } else { f[l - 1] }, c);
    }
    for l in 0..f.len() - 1 {
        // A 2x2 stride-2 transposed convolution: each output pixel sees one input pixel.
        macs += pixels(l) * (f[l + 1] * f[l]) as u64;
        macs += block(l, 2 * f[l], f[l]);
    }
    macs + pixels(0) * f[0] as u64
}

/// The network's view of `layout`'s cells on the padded canonical grid `[h, w]`: 1 in obstacles
/// and outside the room, 0 in free cells.
fn solid_plane(layout: &Layout, [h, w]: [usize; 2]) -> Result<Array2<f32>> {
    let canonical = Frame::of(layout).layout_to_canonical(layout)?;
    let mut plane = Array2::ones((h, w));
    for ((j, i), &s) in canonical.solid().indexed_iter() {
        plane[[j, i]] = f32::from(u8::from(s));
    }
    Ok(plane)
}

/// Writes, into `dir`: `inputs.npy` `[N, C, H, W]` (the bank's network inputs), `outputs.npy`
/// `[N, 1, H, W]` (Burn's raw outputs), `solid.npy` `[H, W]` (1 in obstacles and padding; all
/// on the network's padded canonical grid, [`Surrogate::grid`]), and
/// `weights/<path>.npy` for every parameter. Returns the number of weight tensors.
///
/// # Errors
/// [`Error::Model`] or [`Error::Source`] as for a bank, [`Error::Io`] when `dir` is not writable.
pub fn export_reference(
    model: &Surrogate,
    layout: &Layout,
    sources: &[[f64; 2]],
    dir: &Path,
) -> Result<usize> {
    let [h, w] = model.grid(layout);
    let n = sources.len();
    let chunks = model.inputs(layout, sources)?;
    let mut outputs = Vec::with_capacity(n * h * w);
    for chunk in &chunks {
        outputs.extend(model.forward_raw(chunk.clone(), [h, w])?);
    }
    let inputs: Vec<f32> = chunks.concat();
    let shaped = |values: Vec<f32>, shape: &[usize]| {
        ArrayD::from_shape_vec(IxDyn(shape), values).map_err(|e| Error::Model(e.to_string()))
    };
    io::create_dir_all(&dir.join("weights"))?;
    io::write_npy(
        &dir.join("inputs.npy"),
        &shaped(inputs, &[n, model.channels(), h, w])?,
    )?;
    io::write_npy(&dir.join("outputs.npy"), &shaped(outputs, &[n, 1, h, w])?)?;
    io::write_npy(&dir.join("solid.npy"), &solid_plane(layout, [h, w])?)?;
    let tensors = named_tensors(model.net())?;
    for (name, array) in &tensors {
        io::write_npy(&dir.join("weights").join(format!("{name}.npy")), array)?;
    }
    Ok(tensors.len())
}

/// Seconds for the whole bank of `sources` in `layout` (input encoding, batched forward passes
/// and the inverse transform: what the STE waits for), with the convolutions run by `imp`.
///
/// # Errors
/// As [`Surrogate::predict_many`].
pub fn time_bank(
    model: &Surrogate,
    layout: &Layout,
    sources: &[[f64; 2]],
    imp: ConvImpl,
) -> Result<f64> {
    let start = Instant::now();
    let bank = model.predict_many_with(layout, sources, imp)?;
    let seconds = start.elapsed().as_secs_f64();
    std::hint::black_box(bank);
    Ok(seconds)
}

/// Seconds per training step (forward, masked MSE, backward, AdamW update with the learning
/// rate and weight decay of [`TrainingConfig::default`]) of a fresh network of `model`'s
/// architecture, on batches of `batch` of the bank inputs with `model`'s own outputs as
/// targets, after two warm-up steps, with the convolutions run by `imp`.
///
/// # Errors
/// [`Error::Parameter`] for a zero batch or step count, [`Error::Model`] as for a bank.
pub fn time_training(
    model: &Surrogate,
    layout: &Layout,
    sources: &[[f64; 2]],
    (batch, steps): (usize, usize),
    imp: ConvImpl,
) -> Result<f64> {
    if batch == 0 || steps == 0 || sources.len() < batch {
        return Err(Error::Parameter(format!(
            "training timing needs a batch and steps of at least 1 and {batch} sources"
        )));
    }
    let [h, w] = model.grid(layout);
    let device = plumenet::surrogate::backend::device().autodiff();
    let input = model.inputs(layout, &sources[..batch])?.concat();
    let target = model.forward_raw(input.clone(), [h, w])?;
    let free: Vec<f32> = solid_plane(layout, [h, w])?
        .iter()
        .map(|&s| 1.0 - s)
        .collect::<Vec<_>>()
        .repeat(batch);
    let tensor = |values: Vec<f32>, channels: usize| {
        Tensor::<4>::from_data(TensorData::new(values, [batch, channels, h, w]), &device)
    };
    let (x, y, free) = (
        tensor(input, model.channels()),
        tensor(target, 1),
        tensor(free, 1),
    );
    let mut net = model.saved().architecture.init_seeded(&device, 0);
    let defaults = TrainingConfig::default();
    let mut optim = AdamWConfig::new()
        .with_weight_decay(defaults.weight_decay)
        .init();
    let mut start = Instant::now();
    for step in 0..steps + 2 {
        if step == 2 {
            start = Instant::now();
        }
        // The masked MSE of the target: `defaults` has no relative-L2 term.
        let step_loss = loss(
            &defaults,
            net.forward_with(x.clone(), imp),
            y.clone(),
            free.clone(),
        );
        std::hint::black_box(step_loss.clone().into_scalar::<f32>());
        let grads = GradientsParams::from_grads(step_loss.backward(), &net);
        net = optim.step(defaults.learning_rate, net, grads);
    }
    Ok(start.elapsed().as_secs_f64() / steps as f64)
}

/// The distinct "same" convolutions of `config` on an `[h, w]` grid with `batch` images, each
/// with the number of layers of that shape, shallow to deep.
pub fn conv_layers(
    config: &PlumeNetConfig,
    [h, w]: [usize; 2],
    batch: usize,
) -> Vec<(ConvShape, usize)> {
    let f = &config.filters;
    let k = config.kernel_size;
    // The network pads the grid to a multiple of 2^(levels - 1), then halves it per level.
    let multiple = 1 << (f.len() - 1);
    let shape = |level: usize, cin: usize, cout: usize| ConvShape {
        batch,
        cin,
        cout,
        h: (h.div_ceil(multiple) * multiple) >> level,
        w: (w.div_ceil(multiple) * multiple) >> level,
        k,
    };
    let mut layers: Vec<(ConvShape, usize)> = Vec::new();
    let mut add = |s: ConvShape| match layers.iter_mut().find(|(t, _)| *t == s) {
        Some((_, n)) => *n += 1,
        None => layers.push((s, 1)),
    };
    for (l, &c) in f.iter().enumerate() {
        add(shape(
            l,
            if l == 0 { config.in_channels } else { f[l - 1] },
            c,
        ));
        (1..config.convs_per_level).for_each(|_| add(shape(l, c, c)));
    }
    for l in (0..f.len() - 1).rev() {
        add(shape(l, 2 * f[l], f[l]));
        (1..config.convs_per_level).for_each(|_| add(shape(l, f[l], f[l])));
    }
    layers
}

/// Seconds of one convolution + ReLU of `shape` (random operands) on the training device:
/// the forward pass alone, and the forward and backward passes together (gradients of the
/// input, the weights and the bias), each the median of `repeats` after one warm-up, with our
/// convolution or Burn's.
pub fn time_conv_layer(shape: ConvShape, imp: ConvImpl, repeats: usize) -> (f64, f64) {
    let device = plumenet::surrogate::backend::device().autodiff();
    let ConvShape {
        batch,
        cin,
        cout,
        h,
        w,
        k,
    } = shape;
    let random = |dims: [usize; 4]| {
        Tensor::<4>::random(
            dims,
            burn::tensor::Distribution::Uniform(-1.0, 1.0),
            &device,
        )
    };
    let (x, weight, r) = (
        random([batch, cin, h, w]).require_grad(),
        random([cout, cin, k, k]).require_grad(),
        random([batch, cout, h, w]),
    );
    let bias = Tensor::<1>::zeros([cout], &device).require_grad();
    let run = |backward: bool| {
        let out = match imp {
            ConvImpl::Own => conv2d_same(x.clone(), weight.clone(), bias.clone(), true),
            ConvImpl::Burn => burn_conv2d_same(x.clone(), weight.clone(), bias.clone(), true),
        };
        if backward {
            std::hint::black_box((out * r.clone()).sum().backward());
        } else {
            std::hint::black_box(out.into_data());
        }
    };
    let time = |backward: bool| {
        run(backward);
        let times: Vec<f64> = (0..repeats.max(1))
            .map(|_| {
                let start = Instant::now();
                run(backward);
                start.elapsed().as_secs_f64()
            })
            .collect();
        plumenet::stats::median(&times)
    };
    (time(false), time(true))
}

/// An estimate of the machine's peak single-precision rate.
#[derive(Debug, Clone, PartialEq)]
pub struct CpuPeak {
    /// Cores available to this process.
    pub cores: usize,
    /// Clock (MHz) as `/proc/cpuinfo` reports it.
    pub mhz: f64,
    /// Floating-point operations per cycle and core assumed from the vector extensions: two
    /// fused multiply-add units of 16 (AVX-512) or 8 (AVX2) lanes, or 4 otherwise.
    pub flops_per_cycle: f64,
}

impl CpuPeak {
    /// Peak rate in GFLOP/s.
    pub fn gflops(&self) -> f64 {
        self.cores as f64 * self.mhz * self.flops_per_cycle / 1e3
    }
}

/// The peak estimate of this machine, or `None` where `/proc/cpuinfo` gives no clock.
pub fn cpu_peak() -> Option<CpuPeak> {
    let info = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let mhz = info
        .lines()
        .find(|l| l.starts_with("cpu MHz"))?
        .split(':')
        .nth(1)?
        .trim()
        .parse::<f64>()
        .ok()?;
    let flags = info.lines().find(|l| l.starts_with("flags")).unwrap_or("");
    let has = |f: &str| flags.split_whitespace().any(|x| x == f);
    let lanes = if has("avx512f") {
        16.0
    } else if has("avx2") && has("fma") {
        8.0
    } else {
        2.0
    };
    Some(CpuPeak {
        cores: std::thread::available_parallelism().map_or(1, usize::from),
        mhz,
        flops_per_cycle: 2.0 * 2.0 * lanes,
    })
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use ndarray::{Array4, ArrayD};
    use plumenet::dataset::{self, Distribution, GenerateConfig, GenerateParams};
    use plumenet::surrogate::{TrainingData, train};

    use super::*;

    const COARSE: &str = r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75}}"#;

    /// The coarse arena with one obstacle.
    const BLOCKED: &str = r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75},
    "obstacles":[{"x_min":6,"y_min":1,"x_max":7,"y_max":2}]}"#;

    fn tiny_dataset(dir: &Path) -> TrainingData {
        let config = GenerateConfig {
            distribution: Distribution::Base {
                base: Layout::from_json(COARSE).unwrap().spec().clone(),
                params: GenerateParams::default(),
            },
            layouts: 3,
            sources_per_layout: 4,
            seed: 3,
            shard: None,
        };
        dataset::generate(&config, dir, &|| ()).unwrap();
        TrainingData::load(dir).unwrap()
    }

    fn tiny_config(epochs: usize) -> TrainingConfig {
        TrainingConfig {
            model: PlumeNetConfig::new()
                .with_filters(vec![4, 8])
                .with_convs_per_level(1)
                .with_kernel_size(3),
            epochs,
            batch_size: 4,
            learning_rate: 1e-2,
            patience: 100,
            validation_fraction: 0.34,
            pad_cells: 8,
            ..TrainingConfig::default()
        }
    }

    /// A copy of the model in `from` with mirror averaging on or off.
    fn with_mirror_average(from: &Path, dir: &Path, on: bool) -> Surrogate {
        std::fs::create_dir_all(dir).unwrap();
        std::fs::copy(from.join("weights.bpk"), dir.join("weights.bpk")).unwrap();
        let mut config: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(from.join("config.json")).unwrap())
                .unwrap();
        config["mirror_average"] = serde_json::Value::Bool(on);
        std::fs::write(dir.join("config.json"), config.to_string()).unwrap();
        Surrogate::load(dir).unwrap()
    }

    /// The layer list `bench-net --layers` times covers every 5x5 convolution of the network: 21
    /// layers whose multiply-adds are the forward pass's less the transposed convolutions and the
    /// head.
    #[test]
    fn layer_list_covers_the_network() {
        // DeepCFD's four levels (the one-arena network of `models/arena-v1`).
        let config = PlumeNetConfig::new()
            .with_in_channels(3)
            .with_filters(vec![8, 16, 32, 32]);
        let layers = conv_layers(&config, [32, 144], 1);
        assert_eq!(layers.iter().map(|(_, n)| n).sum::<usize>(), 21);
        let convs: u64 = layers.iter().map(|(s, n)| (s.macs() * n) as u64).sum();
        // Transposed convolutions (one tap per output pixel) and the 1x1 head, by hand.
        let ups = 4608 * 16 * 8 + 1152 * 32 * 16 + 288 * 32 * 32;
        let head = 4608 * 8;
        assert_eq!(convs + ups + head, forward_macs(&config, [32, 144]));
    }

    #[test]
    fn the_pytorch_export_holds_the_bank_and_every_weight_and_the_mac_count_adds_up() {
        let tmp = tempfile::tempdir().unwrap();
        let data = tiny_dataset(&tmp.path().join("data"));
        let dir = tmp.path().join("model");
        let config = tiny_config(1);
        train(&data, &config, &dir, &mut |_| ()).unwrap();
        // The export holds one pass (the room as it is), which is the bank of a one-pass model;
        // trained models average two (`mirror_averaging_is_the_mean_of_the_room_and_its_mirror`).
        assert_eq!(Surrogate::load(&dir).unwrap().views(), 2);
        let model = with_mirror_average(&dir, &tmp.path().join("one-pass"), false);
        let layout = Layout::from_json(BLOCKED).unwrap();
        let candidates = &layout.candidates(0.5).unwrap()[..5];
        let out = tmp.path().join("export");
        let tensors = export_reference(&model, &layout, candidates, &out).unwrap();
        // Weight and bias of 2 encoder convolutions, 1 transposed convolution, 1 decoder
        // convolution and the head.
        assert_eq!(tensors, 10);

        // Burn's raw outputs, transformed back, are the bank (to a few units in the last place:
        // the bank's inverse transform is vectorised, `the_vectorised_inverse_transform_is_expm1`).
        let raw: Array4<f32> = plumenet::io::read_npy(&out.join("outputs.npy")).unwrap();
        let inputs: Array4<f32> = plumenet::io::read_npy(&out.join("inputs.npy")).unwrap();
        assert_eq!(inputs.dim(), (5, 7, 16, 72));
        // The Peclet plane, U dx / D inside the room, and the solved wind relative to the inlet's
        // (uniform far upwind of the obstacle).
        assert!((inputs[[0, 3, 5, 5]] - 0.75 * 0.25 / 0.05).abs() < 1e-6);
        assert!(
            (inputs[[0, 4, 8, 1]] - 1.0).abs() < 0.05,
            "{}",
            inputs[[0, 4, 8, 1]]
        );
        assert!(inputs[[0, 5, 8, 1]].abs() < 0.05);
        let bank = model.predict_many(&layout, candidates).unwrap();
        let norm = model.saved().normalization;
        for ((n, _, j, i), &v) in raw.indexed_iter() {
            let expected = if layout.is_solid(j, i) {
                0.0
            } else {
                norm.inverse(v, layout.wind_speed())
            };
            let got = bank[[n, j, i]];
            assert!(
                (got - expected).abs() <= 5e-7 * expected.abs(),
                "{got} against {expected}"
            );
        }

        // Brute force: every convolution weight times the pixels of the level it writes.
        let levels = config.model.filters.len();
        let mut macs = 0u64;
        for entry in std::fs::read_dir(out.join("weights")).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_stem().unwrap().to_str().unwrap().to_string();
            if !name.ends_with(".weight") {
                continue;
            }
            let w: ArrayD<f32> = plumenet::io::read_npy(&path).unwrap();
            let index = |k: usize| name.split('.').nth(k).unwrap().parse::<usize>().unwrap();
            let level = match name.split('.').next().unwrap() {
                "encoders" => index(1),
                "decoders" | "ups" => levels - 2 - index(1),
                _ => 0,
            };
            let pixels = ((16 >> level) * (72 >> level)) as u64;
            // A 2x2 stride-2 transposed convolution touches each output pixel with one tap.
            let taps = if name.starts_with("ups") { 4 } else { 1 };
            macs += w.len() as u64 * pixels / taps;
        }
        assert_eq!(macs, forward_macs(&config.model, [16, 72]));

        assert!(time_bank(&model, &layout, candidates, ConvImpl::Own).unwrap() > 0.0);
        assert!(time_training(&model, &layout, candidates, (2, 1), ConvImpl::Burn).unwrap() > 0.0);
        assert!(matches!(
            time_training(&model, &layout, candidates, (6, 1), ConvImpl::Own),
            Err(Error::Parameter(_))
        ));
    }
}
