"""The temporal convolutional autoencoder of Lohit et al., Sec. 4.1 (torch; training/export only).

Never imported at run time: ``streamfix.prior.runtime`` runs the exported ONNX graphs.

Architecture (paper Sec. 4.1 and Appendix A.1, sizes scaled to our small data set):

* **Encoder E**: ``levels`` blocks of [1-D convolution over time (kernel 4, 'same'
  padding) -> ReLU -> average pooling by 2], then a fully connected layer to the
  latent ``z`` (``latent`` values). Input channels are the 3J normalised coordinates
  (zero where unobserved, as in the paper) **plus** the J-channel observation mask: a
  zero coordinate is a legitimate root-relative value, so the encoder is told which
  zeros mean "missing" (a deviation from the paper, which feeds zeros only).
* **Decoder D**: the mirror image: a fully connected layer from ``z`` to
  ``channels x (T / 2^levels)`` -> ReLU, then ``levels`` transposed 1-D convolutions
  (kernel 4, stride 2, padding 1: each exactly doubles the frame count) with ReLU
  between them; the last one outputs the 3J coordinates (linear).

Tensors at the ONNX boundary are frame-major, as the rest of streamfix:
``y`` (B, T, J, 3), ``mask`` (B, T, J) float 0/1, ``z`` (B, L), ``x`` (B, T, J, 3).

``DecoderJacobian`` is the decoder with forward-mode differentiation written out
layer by layer (tangent of a linear layer = weight x tangent; of ReLU = tangent x
[pre-activation > 0]), so that one ONNX call returns D(z) and the exact Jacobian
rows dD/dz of every ``JACOBIAN_FRAME_STEP``-th frame (B, L, T/step*J*3) for the
Gauss-Newton solve of Eq. (1), without torch at run time (the exported graph runs the
tangents' products in 8-bit integers, ``JACOBIAN_INT8_TANGENTS``). The exported graphs use the
time-major MatMul form of the transposed convolutions (``DecoderMatmul``), the same
values as the convolutional ``Decoder`` used in training.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["TemporalAutoencoder", "Encoder", "Decoder", "DecoderMatmul", "DecoderJacobian", "JACOBIAN_FRAME_STEP",
           "JACOBIAN_INT8_TANGENTS"]


class Encoder(nn.Module):
    def __init__(self, n_joints: int, window: int, channels: int, latent: int, levels: int, kernel: int = 4):
        super().__init__()
        self.n_joints, self.window = n_joints, window
        c_in = 4 * n_joints
        self.convs = nn.ModuleList()
        for _ in range(levels):
            self.convs.append(nn.Conv1d(c_in, channels, kernel, padding="same"))
            c_in = channels
        self.pool = nn.AvgPool1d(2)
        self.fc = nn.Linear(channels * (window >> levels), latent)

    def forward(self, y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        b = y.shape[0]
        coords = (y * mask.unsqueeze(-1)).reshape(b, self.window, 3 * self.n_joints)
        h = torch.cat([coords, mask], dim=2).transpose(1, 2)  # (B, 4J, T)
        for conv in self.convs:
            h = self.pool(F.relu(conv(h)))
        return self.fc(h.flatten(1))


class Decoder(nn.Module):
    def __init__(self, n_joints: int, window: int, channels: int, latent: int, levels: int):
        super().__init__()
        self.n_joints, self.window, self.channels = n_joints, window, channels
        self.t0 = window >> levels
        self.fc = nn.Linear(latent, channels * self.t0)
        self.deconvs = nn.ModuleList()
        for i in range(levels):
            c_out = 3 * n_joints if i == levels - 1 else channels
            self.deconvs.append(nn.ConvTranspose1d(channels, c_out, 4, stride=2, padding=1))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        b = z.shape[0]
        h = F.relu(self.fc(z)).reshape(b, self.channels, self.t0)
        for i, deconv in enumerate(self.deconvs):
            h = deconv(h)
            if i < len(self.deconvs) - 1:
                h = F.relu(h)
        return h.transpose(1, 2).reshape(b, self.window, self.n_joints, 3)


def _deconv_time_major(h: torch.Tensor, deconv: nn.ConvTranspose1d, frames: int, bias: bool) -> torch.Tensor:
    """``deconv`` (kernel 4, stride 2, padding 1) on time-major ``h`` (M, frames, C_in) -> (M, 2 frames, C_out).

    The same linear map as ``ConvTranspose1d`` on (M, C_in, T), as one MatMul: output frame
    2t+k-1 receives tap k of input frame t, so even frames 2s add taps 1 (frame s) and 3
    (frame s-1), odd frames 2s+1 taps 2 (frame s) and 0 (frame s+1). One
    (M*T, C_in) x (C_in, 4 C_out) product replaces onnxruntime's ConvTranspose (col2im), which
    is slower on these short sequences. ``frames`` is passed as a number so that the exported
    graph has static shapes (only the batch is dynamic).
    """
    c_in, c_out = deconv.in_channels, deconv.out_channels  # numbers, not traced shapes
    taps = h @ deconv.weight.permute(0, 2, 1).reshape(c_in, 4 * c_out)  # (M, T, 4 C_out): taps 0..3
    t0, t1, t2, t3 = torch.split(taps, c_out, dim=2)
    even = t1 + F.pad(t3[:, : frames - 1], (0, 0, 1, 0))
    odd = t2 + F.pad(t0[:, 1:], (0, 0, 0, 1))
    out = torch.stack([even, odd], dim=2).reshape(-1, 2 * frames, c_out)
    return out + deconv.bias if bias else out


def _deconv_even_frames(h: torch.Tensor, deconv: nn.ConvTranspose1d, frames: int) -> torch.Tensor:
    """The even output frames 2s of ``_deconv_time_major`` (no bias): (M, frames, C_in) -> (M, frames, C_out).

    Taps 1 (frame s) and 3 (frame s-1) only: half the product of the full layer.
    """
    c_out = deconv.out_channels
    taps = h @ torch.cat([deconv.weight[:, :, 1], deconv.weight[:, :, 3]], dim=1)  # (M, T, 2 C_out)
    t1, t3 = torch.split(taps, c_out, dim=2)
    return t1 + F.pad(t3[:, : frames - 1], (0, 0, 1, 0))


#: Frame step of the exported Jacobian rows: the Levenberg-Marquardt normal equations of the latent fit
#: are summed over every second frame (x2), which halves the last layer's tangents; at 30 Hz neighbouring
#: frames carry the same information and the held-out D(z*) does not change (benchmarks/bench_prior.py).
JACOBIAN_FRAME_STEP = 2

#: The exported Jacobian graph runs the products of the tangents with each layer's weights (most
#: of its cost) in 8-bit integers (``train.quantize_tangent_products``): the Jacobian only steers the
#: Levenberg-Marquardt step, which is accepted on the float32 cost, and D(z) itself stays float32.
JACOBIAN_INT8_TANGENTS = True


class DecoderMatmul(nn.Module):
    """D(z) in time-major MatMul form (the exported ``decoder`` graph; shares D's weights, same values)."""

    def __init__(self, decoder: Decoder):
        super().__init__()
        self.decoder = decoder

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        d = self.decoder
        h = F.relu(d.fc(z)).reshape(-1, d.channels, d.t0).transpose(1, 2)  # (B, T0, C)
        for i, deconv in enumerate(d.deconvs):
            h = _deconv_time_major(h, deconv, d.t0 << i, bias=True)
            if i < len(d.deconvs) - 1:
                h = F.relu(h)
        return h.reshape(-1, d.window, d.n_joints, 3)


class DecoderJacobian(nn.Module):
    """D(z) and its exact Jacobian by forward-mode propagation of the L unit tangents (shares D's weights).

    Time-major MatMul form (see ``_deconv_time_major``): the tangents of all L directions
    go through each layer as one matrix product. ``frame_step`` 2 (``JACOBIAN_FRAME_STEP``):
    the Jacobian rows of the even frames only, (B, L, T/2*J*3); 1: every frame.
    """

    def __init__(self, decoder: Decoder, latent: int, frame_step: int = JACOBIAN_FRAME_STEP):
        super().__init__()
        if frame_step not in (1, 2):
            raise ValueError(f"frame_step must be 1 or 2, got {frame_step}")
        self.decoder = decoder
        self.latent = latent
        self.frame_step = frame_step

    def forward(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        d = self.decoder
        n_lat = self.latent
        pre = d.fc(z)  # (B, C*T0)
        # tangent of fc for the L unit directions: rows of W^T, the same for every batch item
        tan = d.fc.weight.t().unsqueeze(0) * (pre > 0).to(z.dtype).unsqueeze(1)  # (B, L, C*T0)
        h = F.relu(pre).reshape(-1, d.channels, d.t0).transpose(1, 2)  # (B, T0, C)
        tan = tan.reshape(-1, d.channels, d.t0).transpose(1, 2)  # (B*L, T0, C)
        for i, deconv in enumerate(d.deconvs):
            frames = d.t0 << i
            pre = _deconv_time_major(h, deconv, frames, bias=True)
            last = i == len(d.deconvs) - 1
            if last and self.frame_step == 2:
                tan = _deconv_even_frames(tan, deconv, frames)
            else:
                tan = _deconv_time_major(tan, deconv, frames, bias=False)
            if not last:
                gate = (pre > 0).to(z.dtype)  # (B, 2 frames, C)
                h = pre * gate
                c = deconv.out_channels
                tan = (tan.reshape(-1, n_lat, 2 * frames, c) * gate.unsqueeze(1)).reshape(-1, 2 * frames, c)
            else:
                h = pre
        x = h.reshape(-1, d.window, d.n_joints, 3)
        jac = tan.reshape(-1, n_lat, d.window // self.frame_step * d.n_joints * 3)  # (B, L, T'*J*3), frame-major
        return x, jac


class TemporalAutoencoder(nn.Module):
    """E and D together; ``forward(y, mask) -> D(E(Y))`` (B, T, J, 3)."""

    def __init__(self, n_joints: int = 25, window: int = 64, channels: int = 64, latent: int = 32, levels: int = 4):
        super().__init__()
        if window % (1 << levels):
            raise ValueError(f"window must be a multiple of 2^levels = {1 << levels} frames, got {window}")
        self.config = dict(n_joints=n_joints, window=window, channels=channels, latent=latent, levels=levels)
        self.encoder = Encoder(n_joints, window, channels, latent, levels)
        self.decoder = Decoder(n_joints, window, channels, latent, levels)

    def forward(self, y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.decoder(self.encoder(y, mask))
