//! PlumeNet's own convolution: a stride-1 "same" 2D convolution with its bias and an optional
//! ReLU fused in, added to Burn's Flex backend as a backend-extension operation with a
//! handwritten backward (input, weight and bias gradients) for Flex's autodiff wrapper.
//!
//! The kernels ([`kernel`]) work on plain f32 slices; this module moves Flex tensors in and out
//! of them. [`conv2d_same`] is the one entry point the model calls: on the Flex backend (the
//! default, see [`super::backend::OWN_KERNELS`]) it runs our kernels, on the other backends
//! Burn's own `conv2d` and `relu`. Shapes the kernels do not take (an even or large kernel, a
//! dtype other than f32) fall back to Flex's convolution.

pub mod kernel;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::ops::{ActivationOps, ConvOptions, ModuleOps};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend, Dispatch, Flex, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;

use kernel::{ConvShape, Isa};

/// The fused convolution as a backend operation.
#[backend_extension(Flex, Autodiff)]
pub trait ConvBackend: Backend {
    /// `x` `[B, Cin, H, W]` convolved with `weight` `[Cout, Cin, k, k]` (odd `k`, stride 1,
    /// padding `k / 2`), plus `bias` `[Cout]`, through ReLU if `relu`: `[B, Cout, H, W]`.
    fn conv2d_same(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        relu: bool,
    ) -> FloatTensor<Self>;
}

/// The convolution `x * weight + bias` with "same" padding and stride 1, then ReLU if `relu`.
///
/// `x` is `[B, Cin, H, W]`, `weight` `[Cout, Cin, k, k]` with odd `k`, `bias` `[Cout]`; the
/// result is `[B, Cout, H, W]`. Differentiable on every backend.
pub fn conv2d_same(x: Tensor<4>, weight: Tensor<4>, bias: Tensor<1>, relu: bool) -> Tensor<4> {
    if super::backend::OWN_KERNELS {
        Tensor::from_dispatch(<Dispatch as ConvBackend>::conv2d_same(
            x.into_dispatch(),
            weight.into_dispatch(),
            bias.into_dispatch(),
            relu,
        ))
    } else {
        burn_conv2d_same(x, weight, bias, relu)
    }
}

/// [`conv2d_same`] through Burn's own convolution and ReLU, on any backend (the path before our
/// kernels, kept for the other backends and for comparisons).
pub fn burn_conv2d_same(x: Tensor<4>, weight: Tensor<4>, bias: Tensor<1>, relu: bool) -> Tensor<4> {
    let options = same_options(weight.dims()[2]);
    let out = burn::tensor::module::conv2d(x, weight, Some(bias), options);
    if relu {
        burn::tensor::activation::relu(out)
    } else {
        out
    }
}

/// Stride 1, padding `k / 2`, no dilation, one group: a "same" convolution for odd `k`.
fn same_options(k: usize) -> ConvOptions<2> {
    ConvOptions::new([1, 1], [k / 2, k / 2], [1, 1], 1)
}

/// The f32 values of a Flex tensor in row-major order, with its shape, if it is f32.
fn values(t: &FlexTensor) -> Option<(FlexTensor, Vec<usize>)> {
    (t.dtype() == DType::F32).then(|| (t.to_contiguous(), t.layout().shape().to_vec()))
}

/// A Flex tensor of `shape` holding `data`.
fn tensor(data: Vec<f32>, shape: &[usize]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(data, shape.to_vec()))
}

/// The kernels' shape for these operands, if they take it.
fn shape_of(x: &[usize], weight: &[usize], bias: &[usize]) -> Option<ConvShape> {
    let [b, cin, h, w] = <[usize; 4]>::try_from(x).ok()?;
    let [cout, wcin, k, k2] = <[usize; 4]>::try_from(weight).ok()?;
    let [bcout] = <[usize; 1]>::try_from(bias).ok()?;
    let shape = ConvShape {
        batch: b,
        cin,
        cout,
        h,
        w,
        k,
    };
    (wcin == cin && k2 == k && bcout == cout && shape.supported()).then_some(shape)
}

/// Flex's own convolution (and ReLU), for what our kernels do not take.
fn flex_fallback(x: FlexTensor, weight: FlexTensor, bias: FlexTensor, relu: bool) -> FlexTensor {
    let options = same_options(weight.layout().shape()[2]);
    let out = Flex::conv2d(x, weight, Some(bias), options);
    if relu { Flex::relu(out) } else { out }
}

impl ConvBackend for Flex {
    fn conv2d_same(x: FlexTensor, weight: FlexTensor, bias: FlexTensor, relu: bool) -> FlexTensor {
        let (Some((xc, xs)), Some((wc, ws)), Some((bc, bs))) =
            (values(&x), values(&weight), values(&bias))
        else {
            return flex_fallback(x, weight, bias, relu);
        };
        let Some(shape) = shape_of(&xs, &ws, &bs) else {
            return flex_fallback(x, weight, bias, relu);
        };
        let (Some(xv), Some(wv), Some(bv)) = (
            xc.as_slice::<f32>(),
            wc.as_slice::<f32>(),
            bc.as_slice::<f32>(),
        ) else {
            return flex_fallback(x, weight, bias, relu);
        };
        let out = kernel::forward(Isa::best(), shape, xv, wv, Some(bv), relu);
        tensor(out, &[shape.batch, shape.cout, shape.h, shape.w])
    }
}

/// What the backward pass keeps of the forward: the input, the weights, the bias and, with
/// ReLU, the output (its zeros block the gradient).
#[derive(Debug, Clone)]
struct ConvState {
    x: FlexTensor,
    weight: FlexTensor,
    bias: FlexTensor,
    relu_out: Option<FlexTensor>,
}

#[derive(Debug)]
struct ConvSameBackward;

impl Backward<Flex, 3> for ConvSameBackward {
    type State = ConvState;

    fn backward(self, ops: Ops<ConvState, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let [node_x, node_weight, node_bias] = ops.parents;
        let grad = grads.consume::<Flex>(&ops.node);
        let state = ops.state;
        let (dx, dw, db) = gradients(&state, grad, node_x.is_some());
        if let (Some(node), Some(dx)) = (node_x, dx) {
            grads.register::<Flex>(node.id, dx);
        }
        if let Some(node) = node_weight {
            grads.register::<Flex>(node.id, dw);
        }
        if let Some(node) = node_bias {
            grads.register::<Flex>(node.id, db);
        }
    }
}

/// Input (if `need_x`), weight and bias gradients of the convolution kept in `state`.
fn gradients(
    state: &ConvState,
    grad: FlexTensor,
    need_x: bool,
) -> (Option<FlexTensor>, FlexTensor, FlexTensor) {
    let fast = (|| {
        let (xc, xs) = values(&state.x)?;
        let (wc, ws) = values(&state.weight)?;
        let (_, bs) = values(&state.bias)?;
        let (gc, _) = values(&grad)?;
        let shape = shape_of(&xs, &ws, &bs)?;
        let out = match &state.relu_out {
            Some(o) => Some(values(o)?.0),
            None => None,
        };
        let g = kernel::backward(
            Isa::best(),
            shape,
            xc.as_slice::<f32>()?,
            wc.as_slice::<f32>()?,
            match &out {
                Some(o) => Some(o.as_slice::<f32>()?),
                None => None,
            },
            gc.as_slice::<f32>()?,
            need_x,
        );
        Some((
            g.x.map(|dx| tensor(dx, &xs)),
            tensor(g.weight, &ws),
            tensor(g.bias, &bs),
        ))
    })();
    fast.unwrap_or_else(|| burn_gradients(state, grad, need_x))
}

/// Burn's generic convolution gradients, for what our kernels do not take.
fn burn_gradients(
    state: &ConvState,
    grad: FlexTensor,
    need_x: bool,
) -> (Option<FlexTensor>, FlexTensor, FlexTensor) {
    let grad = match &state.relu_out {
        Some(out) => Flex::relu_backward(out.clone(), grad),
        None => grad,
    };
    let options = same_options(state.weight.layout().shape()[2]);
    let dx = need_x.then(|| {
        Flex::conv2d_x_backward(
            state.x.clone(),
            state.weight.clone(),
            grad.clone(),
            options.clone(),
        )
    });
    let dw =
        Flex::conv2d_weight_backward(state.x.clone(), state.weight.clone(), grad.clone(), options);
    let db = Flex::conv2d_bias_backward(state.x.clone(), state.bias.clone(), grad);
    (dx, dw, db)
}

impl<C: CheckpointStrategy> ConvBackend for Autodiff<Flex, C> {
    fn conv2d_same(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        relu: bool,
    ) -> FloatTensor<Self> {
        let prep = ConvSameBackward
            .prepare::<C>([x.node(), weight.node(), bias.node()])
            .compute_bound()
            .stateful();
        let (x, weight, bias) = (
            x.into_primitive(),
            weight.into_primitive(),
            bias.into_primitive(),
        );
        match prep {
            OpsKind::Tracked(prep) => {
                let out = Flex::conv2d_same(x.clone(), weight.clone(), bias.clone(), relu);
                let state = ConvState {
                    x,
                    weight,
                    bias,
                    relu_out: relu.then(|| out.clone()),
                };
                prep.finish(state, out)
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::conv2d_same(x, weight, bias, relu)),
        }
    }
}
