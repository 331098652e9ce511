"""Sketch -> patch parameters network: ResNet-18 per view (optionally narrower), max-pool over views, MLP head.

The head's output layer starts with zero weights and bias = the template's parameters, so an
untrained network predicts the template exactly (the paper's initialization). With a shape basis
(``train.shape_basis``) the output layer reads out along the basis' directions instead of one
control-point coordinate per output (:class:`BasisReadout`); it starts at the template alike.
"""

from __future__ import annotations

import torch
from torch import nn

from train.resnet import ResNet18

HIDDEN = (1024, 512, 256)


class InkFields(nn.Module):
    """The drawing's darkness (B, 1, H, W) → itself and two Gaussian blurs of it (σ and 3σ px,
    each scaled by σ·√(2π) so a line keeps about its darkness): thin strokes reach the first
    convolution as broad fields, how far a pixel lies from ink."""

    extra_channels = 2  # the two blurs, beside the drawing

    def __init__(self, sigma: float):
        super().__init__()
        kernels = []
        for s in (sigma, 3.0 * sigma):
            r = int(3.0 * s + 0.5)
            x = torch.arange(-r, r + 1, dtype=torch.float32)
            k = torch.exp(-0.5 * (x / s) ** 2)
            kernels.append(k / k.sum())
        self.radii = [len(k) // 2 for k in kernels]
        self.gains = [s * (2.0 * torch.pi) ** 0.5 for s in (sigma, 3.0 * sigma)]
        for i, k in enumerate(kernels):
            self.register_buffer(f"k{i}", k, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = [x]
        for i, r in enumerate(self.radii):
            k = getattr(self, f"k{i}")
            y = nn.functional.conv2d(x, k.view(1, 1, 1, -1), padding=(0, r))
            out.append(self.gains[i] * nn.functional.conv2d(y, k.view(1, 1, -1, 1), padding=(r, 0)))
        return torch.cat(out, dim=1)


class PageCoordinates(nn.Module):
    """(N, C, H, W) → the same with two more channels, x and y across the page from −1 to 1
    (CoordConv, Liu et al. 2018): a convolution sees a stroke's shape, and only through padding and
    strides where it lies, while proportions (where a guitar's waist sits, how wide its body is
    against its length) are positions."""

    extra_channels = 2  # x and y, beside what comes in

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, _, h, w = x.shape
        ys = torch.linspace(-1.0, 1.0, h, device=x.device, dtype=x.dtype).view(1, 1, h, 1).expand(n, 1, h, w)
        xs = torch.linspace(-1.0, 1.0, w, device=x.device, dtype=x.dtype).view(1, 1, 1, w).expand(n, 1, h, w)
        return torch.cat([x, xs, ys], dim=1)


class BasisReadout(nn.Module):
    """features (B, F) -> parameters (B, D) = bias + (features @ weight.T) @ basis.

    ``basis`` (K, D) is a fixed buffer (a shape basis' directions, each one standard deviation of
    the fitted shapes long); ``weight`` (K, F) starts at zero and ``bias`` (D,) at the template,
    so an untrained network predicts the template, as with a plain output layer."""

    def __init__(self, in_features: int, basis: torch.Tensor, initial_params: torch.Tensor):
        super().__init__()
        basis = torch.as_tensor(basis, dtype=torch.float32)
        if basis.dim() != 2 or basis.shape[1] != initial_params.numel():
            raise ValueError(f"basis must be (K, {initial_params.numel()}), got {tuple(basis.shape)}")
        self.weight = nn.Parameter(torch.zeros(basis.shape[0], in_features))
        self.bias = nn.Parameter(initial_params.clone())
        self.register_buffer("basis", basis.clone())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.addmm(self.bias, x @ self.weight.t(), self.basis)


class SketchToPatches(nn.Module):
    """images (B, V, 1, H, W) [+ view mask (B, V)] -> template parameters (B, D)."""

    def __init__(
        self,
        initial_params: torch.Tensor,
        hidden: tuple[int, ...] = HIDDEN,
        encoder_width: int = 64,
        basis: torch.Tensor | None = None,
        input_blur: float = 0.0,
        page_coordinates: bool = False,
        pool_grid: int = 1,
    ):
        super().__init__()
        initial_params = torch.as_tensor(initial_params, dtype=torch.float32).reshape(-1)
        self.num_params = int(initial_params.numel())
        fields: list[InkFields | PageCoordinates] = [InkFields(input_blur)] if input_blur > 0 else []
        fields += [PageCoordinates()] if page_coordinates else []
        self.fields = nn.Sequential(*fields) if fields else nn.Identity()
        self.encoder = ResNet18(1 + sum(f.extra_channels for f in fields), encoder_width, pool_grid)
        dims = (self.encoder.out_features,) + tuple(hidden)
        # One Linear+BatchNorm+ReLU per hidden layer; kept separate so the first hidden layer's
        # activation (the latent used for interpolation) is reachable.
        self.hidden = nn.ModuleList(
            nn.Sequential(nn.Linear(a, b), nn.BatchNorm1d(b), nn.ReLU(inplace=True))
            for a, b in zip(dims[:-1], dims[1:])
        )
        if basis is not None:
            self.out: nn.Module = BasisReadout(dims[-1], basis, initial_params)
            return
        self.out = nn.Linear(dims[-1], self.num_params)
        nn.init.zeros_(self.out.weight)
        with torch.no_grad():
            self.out.bias.copy_(initial_params)

    def encode(self, images: torch.Tensor, view_mask: torch.Tensor | None = None) -> torch.Tensor:
        """Per-view ResNet codes max-pooled over the views present -> (B, 8 × encoder width)."""
        if images.dim() == 4:  # (B, 1, H, W): one view
            images = images.unsqueeze(1)
        b, v = images.shape[:2]
        flat = self.fields(images.flatten(0, 1))
        # read where the mask lives: a mask kept on the host (training's) costs no device read-back
        if view_mask is None or bool(view_mask.all()):
            return self.encoder(flat).view(b, v, -1).max(dim=1).values
        # Only the views present go through the encoder: padding views would cost a pass each and,
        # in training, pull the batch-norm statistics towards blank paper.
        present = view_mask.bool().flatten().nonzero().squeeze(1).to(flat.device, non_blocking=True)
        found = self.encoder(flat.index_select(0, present))
        codes = found.new_full((b * v, found.shape[1]), float("-inf")).index_put((present,), found)
        return codes.view(b, v, -1).max(dim=1).values

    def latent(self, images: torch.Tensor, view_mask: torch.Tensor | None = None) -> torch.Tensor:
        """The first hidden layer's activation (B, 1024): the space `interpolate` blends in."""
        return self.hidden[0](self.encode(images, view_mask))

    def decode_latent(self, z: torch.Tensor) -> torch.Tensor:
        """First-hidden-layer activation -> parameters (B, D)."""
        for layer in self.hidden[1:]:
            z = layer(z)
        return self.out(z)

    def forward(self, images: torch.Tensor, view_mask: torch.Tensor | None = None) -> torch.Tensor:
        """Parameters (B, D)."""
        return self.decode_latent(self.hidden[0](self.encode(images, view_mask)))


class TrainingNet(nn.Module):
    """The network as training calls it: one ``forward`` that also returns what the contrastive
    term needs (the codes of each drawing and of a second drawing of the same model), so
    DistributedDataParallel sees every parameter used. Its parameters are the network's, in the
    same order, then the training-only readout's when there is one."""

    def __init__(self, model: SketchToPatches, readout_params: torch.Tensor | None = None):
        super().__init__()
        self.model = model
        # Training only (--fit-readout): a linear readout of the encoder's codes onto the template's
        # parameters, taught the fit stage's fits, so the encoder learns the shapes without going
        # through the hidden layers and the (slow) output layer. Never handed out: the network's
        # output stays what the paper's loss teaches. Starts at the template, like ``model.out``.
        self.readout: nn.Linear | None = None
        if readout_params is not None:
            readout_params = torch.as_tensor(readout_params, dtype=torch.float32).reshape(-1)
            self.readout = nn.Linear(model.encoder.out_features, readout_params.numel())
            nn.init.zeros_(self.readout.weight)
            with torch.no_grad():
                self.readout.bias.copy_(readout_params)
            self.readout.to(next(model.parameters()).device)

    def forward(
        self,
        images: torch.Tensor,
        view_mask: torch.Tensor | None = None,
        pair_images: torch.Tensor | None = None,
        read_pair: bool = False,
    ) -> dict[str, torch.Tensor]:
        """{"params" (B, D)} plus, with ``pair_images`` (B, 1, H, W), "codes" and "pair_codes" (B, C)
        (and with ``read_pair``, "pair_params" (B, D): the pair's parameters, read in one pass of the
        hidden layers with the sample's), and with a readout, "readout" (B, D): the readout's
        parameters from the same codes."""
        m = self.model
        codes = m.encode(images, view_mask)
        out = {}
        if pair_images is not None:
            out["codes"], out["pair_codes"] = codes, m.encode(pair_images)
        if read_pair and pair_images is not None:
            both = m.decode_latent(m.hidden[0](torch.cat([codes, out["pair_codes"]])))
            out["params"], out["pair_params"] = both[: len(codes)], both[len(codes) :]
        else:
            out["params"] = m.decode_latent(m.hidden[0](codes))
        if self.readout is not None:
            out["readout"] = self.readout(codes)
        return out
