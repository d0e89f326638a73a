"""AgriNeRF field: one density TensoRF shared by an RGB head and a cross-spectral (thermal) head.

Each head is an appearance TensoRF (VM decomposition, Nerfstudio's `TensorVMEncoding`) followed by a small MLP:
MLP_RGB (view dependent, 3 channels) and MLP_THERMAL (1 channel, view independent unless configured otherwise).
A head that the scene does not need is not built at all (no volume, no MLP, no parameters). A scene with temperatures
(a radiometric thermal camera) also gets a temperature head on the thermal appearance (`TemperatureHead`).
"""

from __future__ import annotations

from typing import Dict, Optional, Tuple, Union

import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float
from nerfstudio.cameras.rays import RaySamples
from nerfstudio.data.scene_box import SceneBox
from nerfstudio.field_components.encodings import NeRFEncoding
from nerfstudio.field_components.field_heads import FieldHeadNames
from nerfstudio.field_components.mlp import MLP
from nerfstudio.fields.base_field import Field
from torch import Tensor, nn

from agrinerf_ns.model.device_sync import prune_on
from agrinerf_ns.model.field_heads import AgriNeRFFieldHeadNames
from agrinerf_ns.model.grid_mapping import START_INNER, BoxContraction, axis_resolution
from agrinerf_ns.model.vm_encoding import Resolution, VMCorners, VMLookup, VMVolume, vm_corners


class AppearanceHead(nn.Module):
    """Appearance TensoRF -> linear basis -> MLP -> sigmoid, for one modality.

    Args:
        resolution: initial grid resolution of the appearance volume.
        num_components: VM components per plane/line.
        appearance_dim: size of the feature after the linear basis (TensoRF's `B`).
        out_dim: output channels (3 for RGB, 1 for thermal).
        view_dependent: feed the encoded viewing direction to the MLP.
        mlp_width: hidden width of the MLP (Nerfstudio `MLP` with num_layers=2: one hidden layer, as tensorf's head).
        lookup: how the appearance volume is sampled (`VMLookup`).
    """

    def __init__(
        self,
        resolution: Union[int, Resolution],
        num_components: int,
        appearance_dim: int,
        out_dim: int,
        view_dependent: bool,
        mlp_width: int = 128,
        lookup: VMLookup = "auto",
    ) -> None:
        super().__init__()
        self.encoding = VMVolume(resolution=resolution, num_components=num_components, lookup=lookup)
        self.basis = nn.Linear(self.encoding.get_out_dim(), appearance_dim, bias=False)
        self.feature_encoding = NeRFEncoding(in_dim=appearance_dim, num_frequencies=2, min_freq_exp=0, max_freq_exp=2)
        self.direction_encoding: Optional[NeRFEncoding] = (
            NeRFEncoding(in_dim=3, num_frequencies=2, min_freq_exp=0, max_freq_exp=2) if view_dependent else None
        )
        in_dim = appearance_dim + self.feature_encoding.get_out_dim()
        if self.direction_encoding is not None:
            in_dim += self.direction_encoding.get_out_dim()
        self.mlp = MLP(
            in_dim=in_dim,
            num_layers=2,
            layer_width=mlp_width,
            out_dim=out_dim,
            activation=nn.ReLU(),
            out_activation=nn.Sigmoid(),
            implementation="torch",
        )

    def forward(
        self, coords: Float[Tensor, "n 3"], directions: Float[Tensor, "n 3"], corners: Optional[VMCorners] = None
    ) -> Float[Tensor, "n out_dim"]:
        """Value in [0, 1] at grid coordinates `coords` (in [-1, 1]) seen along unit `directions`; `corners` (of
        `coords`, at the volume's resolution) saves recomputing them."""
        return self.mlp(self.mlp_input(coords, directions, corners))

    def mlp_input(
        self, coords: Float[Tensor, "n 3"], directions: Float[Tensor, "n 3"], corners: Optional[VMCorners] = None
    ) -> Float[Tensor, "n d"]:
        """What the MLP reads: the appearance feature, its encoding and (view dependent) the encoded direction."""
        if corners is None:
            corners = vm_corners(coords, self.encoding.resolution)
        features = self.basis(self.encoding.features(corners))
        parts = [features, self.feature_encoding(features)]
        if self.direction_encoding is not None:
            parts.append(self.direction_encoding(directions))
        return torch.cat(parts, dim=-1)

    def mlp_parameters(self) -> list:
        """Parameters of the basis and MLP (the "fields" optimizer group)."""
        return list(self.basis.parameters()) + list(self.mlp.parameters())


class TemperatureHead(nn.Module):
    """Temperature from the thermal appearance: a small MLP on MLP_THERMAL's input with a linear output, in the
    normalised units (T - mean_c) / std_c of the dataset's temperatures (buffers, saved in checkpoints).

    Its own parameters (``temperature_head.*``), built only for a scene with temperatures: the rescaled thermal outputs
    stay in [0, 1] through their sigmoid, a temperature is unbounded and linear in the camera's calibrated values.
    """

    mean_c: Float[Tensor, ""]
    std_c: Float[Tensor, ""]

    def __init__(self, in_dim: int, width: int, mean_c: float, std_c: float) -> None:
        super().__init__()
        self.mlp = MLP(in_dim=in_dim, num_layers=2, layer_width=width, out_dim=1, activation=nn.ReLU(),
                       out_activation=None, implementation="torch")  # fmt: skip
        self.register_buffer("mean_c", torch.tensor(float(mean_c)))
        self.register_buffer("std_c", torch.tensor(max(float(std_c), 1e-3)))

    def forward(self, mlp_input: Float[Tensor, "n d"]) -> Float[Tensor, "n 1"]:
        return self.mlp(mlp_input)

    def to_celsius(self, normalised: Tensor) -> Tensor:
        return normalised * self.std_c + self.mean_c

    def normalise(self, celsius: Tensor) -> Tensor:
        return (celsius - self.mean_c) / self.std_c


class AgriNeRFField(Field):
    """Shared density TensoRF with optional RGB and thermal appearance heads.

    Args:
        aabb: scene box (2, 3): the grids' box when `contraction` is False (bounded scene), else the first
            full-resolution box (until `refit_box` fits one to the scene).
        contraction: contract the unbounded scene into the grid outside the full-resolution box (`BoxContraction`,
            per axis) so that sky and far trees of an orchard row land in the outer shell of the volumes.
        resolution: initial resolution of all volumes.
        num_density_components: VM components of the density volume.
        with_rgb / with_thermal: build the RGB / thermal head.
        num_rgb_components, rgb_appearance_dim: RGB appearance volume and basis size.
        num_thermal_components, thermal_appearance_dim: thermal appearance volume and basis size.
        thermal_view_dependent: feed the viewing direction to MLP_THERMAL (default: no, thermal is Lambertian enough).
        thermal_channels: outputs of MLP_THERMAL (1: the cross-spectral value; 2: also the thermal camera's value).
        temperature_stats: (mean, std) in degrees C of the dataset's temperatures: builds the temperature head on the
            thermal appearance (`TemperatureHead`); None (no radiometric calibration): no temperature parameters.
        temperature_mlp_width: hidden width of the temperature head.
        mlp_width: hidden width of MLP_RGB.
        thermal_mlp_width: hidden width of MLP_THERMAL (one channel; defaults to `mlp_width`).
        density_shift: added before the softplus (TensoRF's `density_shift`).
        max_density: densities are clamped to this value so that alpha compositing never sees Inf.
        occupancy_resolution: cells per axis of the empty-space occupancy grid (0 disables it).
        vm_lookup: how every volume is sampled (`VMLookup`: row sums on a CPU, `grid_sample` on a GPU by default).
    """

    aabb: Float[Tensor, "2 3"]
    occupancy: Bool[Tensor, "r r r"]

    def __init__(
        self,
        aabb: Float[Tensor, "2 3"],
        contraction: bool = True,
        resolution: int = 128,
        num_density_components: int = 16,
        with_rgb: bool = True,
        with_thermal: bool = True,
        num_rgb_components: int = 48,
        rgb_appearance_dim: int = 27,
        num_thermal_components: int = 16,
        thermal_appearance_dim: int = 12,
        thermal_view_dependent: bool = False,
        thermal_channels: int = 1,
        temperature_stats: Optional[Tuple[float, float]] = None,
        temperature_mlp_width: int = 32,
        mlp_width: int = 128,
        thermal_mlp_width: Optional[int] = None,
        density_shift: float = -4.0,
        max_density: float = 1.0e4,
        occupancy_resolution: int = 64,
        vm_lookup: VMLookup = "auto",
    ) -> None:
        super().__init__()
        if not (with_rgb or with_thermal):
            raise ValueError("AgriNeRFField needs at least one of the RGB and thermal heads")
        self.register_buffer("aabb", aabb.detach().clone().float())
        self.mapping: Optional[BoxContraction] = BoxContraction(self.aabb, START_INNER) if contraction else None
        self.density_encoding = VMVolume(resolution=resolution, num_components=num_density_components, lookup=vm_lookup)
        self.rgb_head: Optional[AppearanceHead] = (
            AppearanceHead(resolution, num_rgb_components, rgb_appearance_dim, 3, True, mlp_width, vm_lookup)
            if with_rgb
            else None
        )
        # the heads of optional modalities draw their initial values from a forked random stream, so that adding a
        # camera leaves the RGB model's initialisation and its training draws as they were (paired ablations)
        with torch.random.fork_rng(devices=[]):
            self.thermal_head: Optional[AppearanceHead] = (
                AppearanceHead(
                    resolution,
                    num_thermal_components,
                    thermal_appearance_dim,
                    thermal_channels,
                    thermal_view_dependent,
                    mlp_width if thermal_mlp_width is None else thermal_mlp_width,
                    vm_lookup,
                )
                if with_thermal
                else None
            )
            self.temperature_head: Optional[TemperatureHead] = None
            if self.thermal_head is not None and temperature_stats is not None:
                in_dim = self.thermal_head.mlp.in_dim
                self.temperature_head = TemperatureHead(in_dim, temperature_mlp_width, *temperature_stats)
        self.density_shift = density_shift
        self.max_density = max_density
        occ_res = max(int(occupancy_resolution), 1)
        self.register_buffer("occupancy", torch.ones((occ_res, occ_res, occ_res), dtype=torch.bool))
        self.occupancy_enabled = occupancy_resolution > 0
        self.occupancy_all = True  # cache: the grid keeps every cell (until the first update; refreshed on load)
        self.register_load_state_dict_post_hook(lambda module, _: module._refresh_occupancy_cache())

    def _refresh_occupancy_cache(self) -> None:
        self.occupancy_all = bool(self.occupancy.all())

    # ---------------------------------------------------------------- geometry
    def volumes(self) -> Dict[str, VMVolume]:
        """Every TensoRF volume of the field, by name (the ones the resolution schedule upsamples)."""
        vols = {"density": self.density_encoding}
        if self.rgb_head is not None:
            vols["rgb"] = self.rgb_head.encoding
        if self.thermal_head is not None:
            vols["thermal"] = self.thermal_head.encoding
        return vols

    def to_grid(self, positions: Float[Tensor, "*bs 3"]) -> Tuple[Float[Tensor, "*bs 3"], Bool[Tensor, "*bs"]]:
        """World positions -> grid coordinates in [-1, 1] and a mask of positions inside the volume."""
        positions = torch.nan_to_num(positions.float(), nan=0.0, posinf=1e6, neginf=-1e6)
        if self.mapping is not None:
            coords = self.mapping(positions)
        else:
            coords = SceneBox.get_normalized_positions(positions, self.aabb) * 2.0 - 1.0
        inside = ((coords > -1.0) & (coords < 1.0)).all(dim=-1)
        return coords.clamp(-1.0, 1.0), inside

    def full_resolution_box(self) -> Float[Tensor, "2 3"]:
        """World lo / hi corners of the region where the grids have their full resolution (the fitted box; the scene
        box of a bounded field)."""
        return self.mapping.box() if self.mapping is not None else self.aabb.clone()

    def full_resolution(self, positions: Float[Tensor, "*bs 3"]) -> Bool[Tensor, "*bs"]:
        """Whether each world position lies where the grids have their full resolution."""
        box = self.full_resolution_box()
        return ((positions >= box[0]) & (positions <= box[1])).all(dim=-1)

    def voxel_size(
        self, positions: Float[Tensor, "*bs 3"], resolution: Optional[Resolution] = None
    ) -> Float[Tensor, "*bs 3"]:
        """World size of a grid cell along each axis at each position, at `resolution` (default: the volumes')."""
        res = self.density_encoding.resolution if resolution is None else resolution
        if self.mapping is not None:
            return self.mapping.voxel_size(positions, res)
        extent = self.aabb[1] - self.aabb[0]
        cell = extent / (torch.tensor(res, dtype=extent.dtype, device=extent.device) - 1.0)
        return cell.expand(*positions.shape[:-1], 3)

    def axis_resolution(self, cube: int) -> Resolution:
        """Grid points per axis for the voxel budget of a `cube`^3 grid, with cells of one size in the box."""
        if self.mapping is None:
            return axis_resolution(self.aabb, 1.0, cube)
        return self.mapping.axis_resolution(cube)

    @torch.no_grad()
    def refit_box(self, box: Float[Tensor, "2 3"], inner: float, cube: int) -> None:
        """Fit the full-resolution box to `box` (grid fraction `inner`) and resample every volume into it, at the
        resolution per axis of a `cube`^3 budget. Exact at the new grid points: each plane and line is resampled
        along its own axes (`VMVolume.resample`). The occupancy grid (in grid coordinates) keeps every cell again."""
        if self.mapping is None:
            raise ValueError("A bounded field (no contraction) keeps its scene box")
        old = BoxContraction(self.mapping.box(), self.mapping.inner_value).to(self.aabb.device)
        self.mapping.set_box(box, inner)
        res = self.axis_resolution(cube)
        # per axis: the new grid points, in world coordinates, in the old grid's coordinates
        grid = [torch.linspace(-1.0, 1.0, r, device=self.aabb.device) for r in res]
        sources = []
        for axis, g in enumerate(grid):
            coords = torch.zeros(g.shape[0], 3, device=g.device)
            coords[:, axis] = g
            sources.append(old(self.mapping.inverse(coords))[:, axis])
        for volume in self.volumes().values():
            volume.resample(res, sources)
        self.occupancy.fill_(True)
        self._refresh_occupancy_cache()

    def occupied(self, coords: Float[Tensor, "n 3"]) -> Bool[Tensor, " n"]:
        """Whether each grid coordinate falls in a cell that the occupancy grid keeps."""
        if not self.occupancy_enabled or self.occupancy_all:
            return torch.ones(coords.shape[0], dtype=torch.bool, device=coords.device)
        res = self.occupancy.shape[0]
        idx = ((coords + 1.0) * (res / 2.0)).long().clamp(0, res - 1)
        return self.occupancy[idx[:, 0], idx[:, 1], idx[:, 2]]

    def corners(self, coords: Float[Tensor, "n 3"]) -> VMCorners:
        """Lookup corners of flat grid coordinates, shared by every volume (they all have one resolution)."""
        return vm_corners(coords, self.density_encoding.resolution)

    def density_at(
        self, coords: Float[Tensor, "*bs 3"], valid: Bool[Tensor, "*bs"], corners: Optional[VMCorners] = None
    ) -> Float[Tensor, "*bs 1"]:
        """Density (softplus of the summed VM features, clamped) at `coords`; zero where `valid` is False.

        Only the valid, occupied points are looked up in the volume, so empty space costs nothing. `corners` (of the
        flattened `coords`) saves recomputing them.
        """
        flat = coords.reshape(-1, 3)
        keep = valid.reshape(-1) & self.occupied(flat)
        if corners is None:
            corners = self.corners(flat)
        if not prune_on(flat):  # a GPU: every point, masked after (a data-dependent prune would wait on the GPU)
            raw = self.density_encoding.features(corners).sum(dim=-1, keepdim=True)
            density = torch.where(keep[:, None], F.softplus(raw + self.density_shift).clamp(max=self.max_density), 0.0)
            return density.reshape(*coords.shape[:-1], 1)
        if bool(keep.all()):  # nothing to prune: no gather/scatter
            raw = self.density_encoding.features(corners).sum(dim=-1, keepdim=True)
            density = F.softplus(raw + self.density_shift).clamp(max=self.max_density)
            return density.reshape(*coords.shape[:-1], 1)
        density = flat.new_zeros(flat.shape[0], 1)
        if keep.any():
            raw = self.density_encoding.features(corners.select(keep)).sum(dim=-1, keepdim=True)
            density[keep] = F.softplus(raw + self.density_shift).clamp(max=self.max_density)
        return density.reshape(*coords.shape[:-1], 1)

    def get_density(self, ray_samples: RaySamples) -> Tuple[Float[Tensor, "*bs 1"], Float[Tensor, "*bs 3"]]:
        """Field contract: (density, embedding); the embedding is the sample's grid coordinate in [-1, 1]."""
        coords, inside = self.to_grid(ray_samples.frustums.get_positions())
        return self.density_at(coords, inside), coords

    # -------------------------------------------------------------- appearance
    def appearance_at(
        self,
        coords: Float[Tensor, "n 3"],
        directions: Float[Tensor, "n 3"],
        corners: Optional[VMCorners] = None,
        heads: Optional[Tuple[str, ...]] = None,
    ) -> Dict[object, Float[Tensor, "n c"]]:
        """Head outputs at flat grid coordinates (used by the model on the samples that matter only); both heads
        share one set of lookup corners (`corners`, when given, must be those of `coords`). `heads`: any of "rgb",
        "thermal" and "temperature" to evaluate; None: every head built."""
        directions = torch.nan_to_num(directions.float())  # unit vectors (Nerfstudio's rays are normalised)
        if corners is None:
            corners = self.corners(coords)
        out: Dict[object, Tensor] = {}
        if self.rgb_head is not None and (heads is None or "rgb" in heads):
            out[FieldHeadNames.RGB] = self.rgb_head(coords, directions, corners)
        thermal = self.thermal_head is not None and (heads is None or "thermal" in heads)
        temperature = self.temperature_head is not None and (heads is None or "temperature" in heads)
        if self.thermal_head is not None and (thermal or temperature):  # the temperature head reads the same input
            thermal_input = self.thermal_head.mlp_input(coords, directions, corners)
            if thermal:
                out[AgriNeRFFieldHeadNames.THERMAL] = self.thermal_head.mlp(thermal_input)
            if temperature:
                assert self.temperature_head is not None
                out[AgriNeRFFieldHeadNames.TEMPERATURE] = self.temperature_head(thermal_input)
        return out

    def get_outputs(
        self, ray_samples: RaySamples, density_embedding: Optional[Tensor] = None
    ) -> Dict[object, Float[Tensor, "*bs c"]]:
        """Field contract: head outputs at every sample, keyed by `FieldHeadNames.RGB` / `AgriNeRFFieldHeadNames`."""
        if density_embedding is None:
            density_embedding, _ = self.to_grid(ray_samples.frustums.get_positions())
        shape = density_embedding.shape[:-1]
        flat = self.appearance_at(density_embedding.reshape(-1, 3), ray_samples.frustums.directions.reshape(-1, 3))
        return {k: v.reshape(*shape, v.shape[-1]) for k, v in flat.items()}

    # --------------------------------------------------------------- pruning
    @torch.no_grad()
    def update_occupancy(self, density_threshold: float, chunk: int = 1 << 16) -> float:
        """Recompute the occupancy grid from the density volume; returns the fraction of cells kept.

        A cell is kept when the density at its centre or at a jittered point in it exceeds `density_threshold`; the
        result is dilated by one cell so that surfaces on cell borders are not cut (TensoRF's alpha mask, simplified).
        When no cell passes (an update too early in training) the grid is left as it is.
        """
        if not self.occupancy_enabled:
            return 1.0
        res = self.occupancy.shape[0]
        device = self.occupancy.device
        axis = (torch.arange(res, device=device, dtype=torch.float32) + 0.5) / res * 2.0 - 1.0
        centres = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), dim=-1).reshape(-1, 3)
        gen = torch.Generator(device="cpu").manual_seed(res)  # cpu: the jitter, alike on every device
        jitter = (torch.rand(centres.shape, generator=gen) - 0.5).to(device) * (2.0 / res)  # cpu: same on every device
        dens = torch.zeros(centres.shape[0], device=device)
        for pts in (centres, centres + jitter):
            for start in range(0, pts.shape[0], chunk):
                part = pts[start : start + chunk].clamp(-1.0, 1.0)
                raw = self.density_encoding(part).sum(dim=-1)
                val = F.softplus(raw + self.density_shift)
                dens[start : start + chunk] = torch.maximum(dens[start : start + chunk], val)
        occ = (dens > density_threshold).reshape(1, 1, res, res, res).float()
        occ = F.max_pool3d(occ, kernel_size=3, stride=1, padding=1)[0, 0] > 0
        if not bool(occ.any()):
            # nothing is dense yet (too early in training): pruning everything would stop all learning, keep the grid
            return float(self.occupancy.float().mean().item())
        self.occupancy.copy_(occ)
        self._refresh_occupancy_cache()
        return float(occ.float().mean().item())
