"""Shared by tests/models/test_production_*.py: the MaterialX node definitions the production coat
models transcribe (loaded with the MaterialX Python API), a small evaluator of their float/colour
node graphs, and a height-correlated GGX BRDF in angle form (independent of goniometer.optics)."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import MaterialX as mx  # pinned in the test extra of pyproject.toml
import numpy as np

from tests.models.helpers import angle, ggx_d_tb, half, lambda_tb, polar

OPENPBR = ("open_pbr_surface.mtlx", "ND_open_pbr_surface_surfaceshader", "NG_open_pbr_surface_surfaceshader")
STANDARD_SURFACE = ("standard_surface.mtlx", "ND_standard_surface_surfaceshader", "NG_standard_surface_surfaceshader_100")


@lru_cache(maxsize=None)
def _document(file: str):
    """The MaterialX document of ``file`` (kept alive: its elements refer to it)."""
    path = Path(mx.__file__).parent / "libraries" / "bxdf" / file
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(path))
    return doc


def load(which: tuple[str, str, str]):
    """``(nodedef, nodegraph)`` of ``which`` from the installed MaterialX library."""
    doc = _document(which[0])
    nodedef = doc.getNodeDef(which[1])
    graph = doc.getNodeGraph(which[2])
    assert nodedef is not None and graph is not None, f"{which} not found in {path}"
    return nodedef, graph


def input_names(nodedef) -> list[str]:
    """Names of every input of ``nodedef``, inherited ones included."""
    return [i.getName() for i in nodedef.getActiveInputs()]


def _parse(text: str) -> np.ndarray:
    return np.array([float(x) for x in text.split(",")])


class GraphEvaluator:
    """Evaluates the float/colour nodes of a MaterialX node graph for given interface values.

    Supports the categories the coat formulas use; ``mix(fg, bg, m) = bg + m (fg - bg)``
    (MaterialX's definition). Interface inputs not given take the node definition's defaults.
    """

    OPS = {
        "add": lambda a, b: a + b, "subtract": lambda a, b: a - b, "multiply": lambda a, b: a * b,
        "divide": lambda a, b: a / b, "power": lambda a, b: a ** b, "min": np.minimum, "max": np.maximum,
    }

    def __init__(self, nodedef, graph, values: dict[str, float | tuple]):
        self.nodedef = nodedef
        self.graph = graph
        self.values = {k: np.asarray(v, dtype=float) for k, v in values.items()}

    def interface(self, name: str) -> np.ndarray:
        if name in self.values:
            return self.values[name]
        return _parse(self.nodedef.getActiveInput(name).getValueString())

    def input(self, node, name: str) -> np.ndarray:
        inp = node.getInput(name)
        assert inp is not None, f"{node.getName()} has no input {name}"
        if inp.getInterfaceName():
            return self.interface(inp.getInterfaceName())
        if inp.getNodeName():
            return self.node(inp.getNodeName())
        return _parse(inp.getValueString())

    def node(self, name: str) -> np.ndarray:
        node = self.graph.getNode(name)
        assert node is not None, f"no node {name} in {self.graph.getName()}"
        cat = node.getCategory()
        if cat in self.OPS:
            return self.OPS[cat](self.input(node, "in1"), self.input(node, "in2"))
        if cat == "mix":
            fg, bg, m = self.input(node, "fg"), self.input(node, "bg"), self.input(node, "mix")
            return bg + m * (fg - bg)
        if cat == "convert":
            return self.input(node, "in") * np.ones(3)
        if cat == "clamp":
            return np.clip(self.input(node, "in"), self.input(node, "low") if node.getInput("low") else 0.0,
                           self.input(node, "high") if node.getInput("high") else 1.0)
        raise NotImplementedError(f"node category {cat} ({name})")


def ggx_brdf_hc_tb(l: np.ndarray, v: np.ndarray, alpha: float, fresnel) -> float:
    """F D G2 / (4 cos cos) with height-correlated G2 = 1 / (1 + Lambda(l) + Lambda(v)) and
    F = fresnel(angle between v and h)."""
    h = half(l, v)
    g2 = 1.0 / (1.0 + lambda_tb(polar(l), alpha) + lambda_tb(polar(v), alpha))
    return float(fresnel(angle(v, h)) * ggx_d_tb(polar(h), alpha) * g2 / (4.0 * l[2] * v[2]))


def hemisphere_rule(n_mu: int, n_phi: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions (N, 3) of the upper hemisphere and weights w (N,) with sum w g(d) ~ Int g(d) cos dd:
    Gauss-Legendre in mu = cos theta on (0, 1), midpoint in phi."""
    x, wx = np.polynomial.legendre.leggauss(n_mu)
    mu = 0.5 * (x + 1.0)
    wmu = 0.5 * wx
    phi = (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    m, p = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - m * m)
    d = np.stack([s * np.cos(p), s * np.sin(p), m], axis=-1).reshape(-1, 3)
    w = (wmu[:, None] * mu[:, None] * np.full((1, n_phi), 2.0 * np.pi / n_phi)).reshape(-1)
    return d, w
