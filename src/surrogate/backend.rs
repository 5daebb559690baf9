//! The one place where the compute backend is chosen, at compile time.
//!
//! Default: Burn's Flex CPU backend (measured 4.5x faster inference and ~28x faster training
//! than NdArray on a 2-core machine). `--features ndarray-backend` selects NdArray, `cuda` or
//! `wgpu` a GPU.

use burn::prelude::Device;

/// Whether PlumeNet's convolutions run our own kernels ([`super::conv`]), which exist for the
/// Flex backend only; the other backends use Burn's convolution.
pub const OWN_KERNELS: bool = cfg!(not(any(
    feature = "cuda",
    feature = "wgpu",
    feature = "ndarray-backend"
)));

/// The inference device (call `.autodiff()` on it for training).
#[cfg(not(any(feature = "cuda", feature = "wgpu", feature = "ndarray-backend")))]
pub fn device() -> Device {
    Device::flex()
}

/// The inference device (call `.autodiff()` on it for training).
#[cfg(all(
    feature = "ndarray-backend",
    not(any(feature = "cuda", feature = "wgpu"))
))]
#[allow(deprecated)]
pub fn device() -> Device {
    Device::ndarray()
}

/// The inference device (call `.autodiff()` on it for training).
#[cfg(feature = "cuda")]
pub fn device() -> Device {
    Device::cuda(0)
}

/// The inference device (call `.autodiff()` on it for training).
#[cfg(all(feature = "wgpu", not(feature = "cuda")))]
pub fn device() -> Device {
    Device::default()
}
