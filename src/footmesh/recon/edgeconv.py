"""The EdgeConv (DGCNN) point-cloud baseline of thesis 3.3.1, and the Chamfer distance it is trained with.

EdgeConv (Wang et al., Dynamic Graph CNN): for every point i, the k nearest points j in the *current feature
space* (self included, thesis eq. 3.1: i = j is allowed, so each point also sees itself), edge features
``h(x_i, x_j - x_i)`` by a shared layer, and a max over the neighbours. The graph is rebuilt at every layer
(dynamic). As in the thesis, which appends "up-sampling layers with the same approximated convolutional
operator" to DGCNN to predict points instead of a class, the generator here is

    latent (B, C_in) --linear--> seed features (B, N_0, c_0)
    stage s: EdgeConv(k_s) -> [up-sample x r_s: each point's features -> r_s children by a linear map]
    point-wise linear -> normalised centred coordinates -> mm (``decoder.CentredOutput``, as the mesh decoder)

giving N = N_0 x prod(r_s) points (default 256 x 4 x 4 = 4,096) in the camera frame. A stage with k = 1 is
point-wise (the thesis' PointNet analogy: only the self-loop); the default uses it for the 4,096-point stage,
where a k-NN graph over a batch would cost (B, 4096, 4096) distances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

from footmesh.recon.decoder import CentredOutput, OutputScale

NEGATIVE_SLOPE = 0.2
"""LeakyReLU slope of DGCNN."""


@dataclass(frozen=True)
class EdgeConvConfig:
    """Sizes of ``EdgeConvGenerator``: one entry of ``channels`` and ``k`` per stage, one up-sampling between."""

    in_features: int = 512
    seed_points: int = 256
    channels: tuple[int, ...] = (64, 64, 32)
    k: tuple[int, ...] = (16, 16, 1)
    """Neighbours per point (self included) at each stage; 1 = point-wise."""
    up_factors: tuple[int, ...] = (4, 4)
    output: OutputScale = field(default_factory=OutputScale)

    @property
    def num_points(self) -> int:
        return self.seed_points * math.prod(self.up_factors)


@dataclass(frozen=True)
class PointCloudOutput:
    """What ``EdgeConvGenerator`` returns."""

    points: torch.Tensor  # (B, N, 3) mm, camera frame (unordered: compare with chamfer_distance)
    centre: torch.Tensor  # (B, 3) mm, the points' centroid


def knn(x: torch.Tensor, k: int) -> torch.Tensor:
    """Indices of the k nearest points of each point in feature space, itself first: (B, N, C) -> (B, N, k).

    Squared distances in the expanded form of thesis eq. 3.2, ``|x_i|^2 + |x_j|^2 - 2 x_i . x_j``.
    """
    b, n, _ = x.shape
    if not 1 <= k <= n:
        raise ValueError(f"k must lie in [1, {n}], got {k}")
    sq = (x * x).sum(dim=-1)
    dist = sq.unsqueeze(2) + sq.unsqueeze(1) - 2.0 * x @ x.transpose(1, 2)  # (B, N, N)
    # the self-loop always comes first, whatever the rounding of its (zero) distance
    dist.diagonal(dim1=1, dim2=2).fill_(-1.0)
    return dist.topk(k, dim=-1, largest=False).indices


class EdgeConv(nn.Module):
    """``x_i' = max_j LeakyReLU(W [x_i, x_j - x_i] + b)`` over the k nearest neighbours j (dynamic graph).

    With one linear layer and a monotonic activation the maximum can be taken before the activation, and
    ``W [x_i, x_j - x_i] = (W_1 - W_2) x_i + W_2 x_j``: the (B, N, k, C_out) edge tensor reduces to a max over
    gathered rows of ``W_2 x`` (identical result, less memory).

    Shapes:
        (B, N, C_in) -> (B, N, C_out).
    """

    def __init__(self, in_channels: int, out_channels: int, k: int) -> None:
        super().__init__()
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        self.in_channels, self.out_channels, self.k = in_channels, out_channels, k
        self.linear = nn.Linear(2 * in_channels, out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, N, C_in) -> (B, N, C_out)."""
        if x.dim() != 3 or x.shape[2] != self.in_channels:
            raise ValueError(f"features must be (B, N, {self.in_channels}), got {tuple(x.shape)}")
        b, n, _ = x.shape
        w_centre, w_edge = self.linear.weight[:, : self.in_channels], self.linear.weight[:, self.in_channels :]
        centre = F.linear(x, w_centre - w_edge, self.linear.bias)  # (B, N, C_out)
        edge = F.linear(x, w_edge)
        if self.k == 1:
            best = edge  # the self-loop only
        else:
            idx = knn(x.detach(), self.k)  # (B, N, k); the graph is not differentiated (DGCNN)
            gathered = edge.gather(1, idx.reshape(b, n * self.k, 1).expand(-1, -1, self.out_channels))
            best = gathered.reshape(b, n, self.k, self.out_channels).amax(dim=2)
        return F.leaky_relu(centre + best, NEGATIVE_SLOPE)

    def extra_repr(self) -> str:
        return f"{self.in_channels}, {self.out_channels}, k={self.k}"


class PointUpsample(nn.Module):
    """Each point's features -> ``factor`` children by a shared linear map: (B, N, C) -> (B, N * factor, C_out)."""

    def __init__(self, in_channels: int, out_channels: int, factor: int) -> None:
        super().__init__()
        if factor < 1:
            raise ValueError(f"up-sampling factor must be >= 1, got {factor}")
        self.factor, self.out_channels = factor, out_channels
        self.linear = nn.Linear(in_channels, factor * out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, n, _ = x.shape
        children = self.linear(x).reshape(b, n * self.factor, self.out_channels)  # children of i: i*f .. i*f+f-1
        return F.leaky_relu(children, NEGATIVE_SLOPE)


class EdgeConvGenerator(nn.Module):
    """Latent code (B, C_in) -> point cloud (B, N, 3) in mm, camera frame (thesis 3.3.1 baseline)."""

    def __init__(self, config: EdgeConvConfig | None = None) -> None:
        super().__init__()
        cfg = config if config is not None else EdgeConvConfig()
        if len(cfg.k) != len(cfg.channels) or len(cfg.up_factors) != len(cfg.channels) - 1:
            raise ValueError(
                f"EdgeConvConfig: {len(cfg.channels)} stages need as many k and one up-sampling fewer, got "
                f"k={cfg.k} and up_factors={cfg.up_factors}"
            )
        sizes = [cfg.seed_points]
        for r in cfg.up_factors:
            sizes.append(sizes[-1] * r)
        too_many = [(kk, s) for kk, s in zip(cfg.k, sizes, strict=True) if kk > s]
        if too_many:
            raise ValueError(f"EdgeConvConfig: k exceeds the points of its stage: {too_many}")
        self.config = cfg
        self.seed = nn.Linear(cfg.in_features, cfg.seed_points * cfg.channels[0])
        self.convs = nn.ModuleList()
        self.upsample = nn.ModuleList()
        in_channels = cfg.channels[0]
        for stage, (c, kk) in enumerate(zip(cfg.channels, cfg.k, strict=True)):
            self.convs.append(EdgeConv(in_channels, c, kk))
            if stage < len(cfg.up_factors):
                nxt = cfg.channels[stage + 1]
                self.upsample.append(PointUpsample(c, nxt, cfg.up_factors[stage]))
                in_channels = nxt
        self.head = nn.Linear(cfg.channels[-1], 3)
        self.output = CentredOutput(cfg.in_features, cfg.output)

    def forward(self, latent: torch.Tensor) -> PointCloudOutput:
        """(B, in_features) -> ``PointCloudOutput`` with points (B, N, 3) and centre (B, 3), mm."""
        cfg = self.config
        if latent.dim() != 2 or latent.shape[1] != cfg.in_features:
            raise ValueError(f"latent must be (B, {cfg.in_features}), got {tuple(latent.shape)}")
        x = F.leaky_relu(self.seed(latent), NEGATIVE_SLOPE).reshape(latent.shape[0], cfg.seed_points, cfg.channels[0])
        for stage, conv in enumerate(self.convs):
            x = conv(x)
            if stage < len(self.upsample):
                x = self.upsample[stage](x)
        centre = self.output.centre(latent)
        return PointCloudOutput(self.output(self.head(x), centre), centre)

    def extra_repr(self) -> str:
        n = sum(p.numel() for p in self.parameters())
        return f"points={self.config.num_points}, parameters={n}"


def chamfer_distance(a: torch.Tensor, b: torch.Tensor, squared: bool = False) -> torch.Tensor:
    """Symmetric Chamfer distance between point clouds: the mean of both directions' mean nearest distance.

    ``0.5 * (mean_i min_j |a_i - b_j| + mean_j min_i |a_i - b_j|)``, in the clouds' unit (mm): it reads as an
    average point-to-cloud distance. ``squared=True`` uses squared distances (the usual training form, mm^2).

    Args:
        a: (B, N, D). b: (B, M, D).
    Returns:
        (B,) per cloud pair; exactly 0 for identical clouds, and symmetric in ``a`` and ``b``.
    """
    if a.dim() != 3 or b.dim() != 3 or a.shape[0] != b.shape[0] or a.shape[2] != b.shape[2]:
        raise ValueError(f"point clouds must be (B, N, D) and (B, M, D), got {tuple(a.shape)} and {tuple(b.shape)}")
    nearest_in_b, nearest_in_a = _nearest_neighbours(a.detach(), b.detach())
    # distances of the chosen pairs by direct subtraction: exact (0 for identical points) and differentiable
    to_b = a - b.gather(1, nearest_in_b.unsqueeze(-1).expand(-1, -1, a.shape[2]))
    to_a = b - a.gather(1, nearest_in_a.unsqueeze(-1).expand(-1, -1, b.shape[2]))
    if squared:
        d_ab, d_ba = (to_b * to_b).sum(dim=-1), (to_a * to_a).sum(dim=-1)
    else:
        d_ab, d_ba = torch.linalg.vector_norm(to_b, dim=-1), torch.linalg.vector_norm(to_a, dim=-1)
    return 0.5 * (d_ab.mean(dim=1) + d_ba.mean(dim=1))


def _nearest_neighbours(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For each point of a its nearest point in b (B, N), and for each point of b its nearest in a (B, M)."""
    to_b, to_a = [], []
    with torch.no_grad():
        for ai, bi in zip(a, b, strict=True):  # one (N, M) distance matrix at a time
            # centred on b's mean: the fast |a|^2 + |b|^2 - 2ab form then loses only ~1e-3 mm^2 in float32, which
            # can at worst pick a neighbour 0.05 mm farther than the nearest; the distances themselves are exact
            centre = bi.mean(dim=0, keepdim=True)
            ac, bc = (ai - centre).unsqueeze(0), (bi - centre).unsqueeze(0)
            # row-wise minima of two products are faster on CPU than one product's column-wise minimum
            to_b.append(torch.cdist(ac, bc).squeeze(0).min(dim=1).indices)  # (N,)
            to_a.append(torch.cdist(bc, ac).squeeze(0).min(dim=1).indices)  # (M,)
    return torch.stack(to_b), torch.stack(to_a)
