"""``LightEstimate``: what photometric registration produces, and its exchange formats.

A light estimate is one *main* directional light, optionally more explicit lights, and
the radiance SH of everything else (the "ambient" remainder), plus an optional HDR
equirect map, a timestamp and a confidence. The lights and the SH partition the
environment's energy: main + extra lights + SH = the map (see :mod:`arlight.light.extract`).

JSON layouts (:meth:`LightEstimate.to_json` / :meth:`LightEstimate.from_json`):

``"arlight"`` (lossless, ours)
    every field, SH of any order in our basis (``docs/conventions.md``), floats written
    with ``repr`` precision; the HDR map goes to an EXR file next to the JSON.
``"arcore"`` (ARCore Environmental HDR)
    ``environmentalHdrAmbientSphericalHarmonics``: 27 floats, interleaved
    ``[r0, g0, b0, r1, ...]``, radiance SH in the Condon-Shortley-phase real basis written
    in Cartesian world coordinates (``y_1^{-1} = -0.488603 y``, ``y_1^0 = 0.488603 z``,
    ``y_1^1 = -0.488603 x``, ...; Filament's basis). These are *not* pre-multiplied:
    ARCore's hello_ar sample multiplies them in the app by ``y_lm`` constant x ``A_l / pi``
    (``0.282095, -0.325735, 0.325735, -0.325735, 0.273137, -0.273137, 0.078848,
    -0.273137, 0.136569``) before the shader evaluates ``E/pi`` at the world normal;
    :func:`arcore_shader_factors` gives these numbers. ``environmentalHdrMainLightDirection``
    points *toward* the light (the sample uses ``dot(normal, direction)``),
    ``environmentalHdrMainLightIntensity`` is RGB irradiance on a surface facing the light
    (the sample shades ``albedo/pi * intensity * n.l``); ``timestamp`` in nanoseconds.
    ARCore's SH are *ambient*: the main light is not in them.
``"arkit"`` (``ARDirectionalLightEstimate``)
    ``sphericalHarmonicsCoefficients``: 27 floats in three *planes* (9 red, 9 green,
    9 blue); ``primaryLightDirection`` and ``primaryLightIntensity``. Apple documents
    neither the SH basis signs nor which way the direction points; we assume the basis
    without the Condon-Shortley phase and the direction the light *travels* (SceneKit's
    light orientation). ``primaryLightIntensity`` is "the estimated intensity, in lumens,
    of the strongest directional light source", scaled for SceneKit where 1000 lumens is
    "neutral" (Apple: ``ARDirectionalLightEstimate.primaryLightIntensity``,
    ``ARLightEstimate.ambientIntensity``, ``SCNLight.intensity``, default 1000 lm). We
    write ``1000 Y(E) / pi`` with ``E`` the main light's irradiance: *assumption*: a map
    value of 1.0 is the camera's neutral white, and a light of 1000 lm (colour factor 1 in
    SceneKit) makes a white diffuse surface facing it show 1.0, which a physical
    Lambertian surface shows under ``E = pi``. Reading it back gives grey
    ``E = pi I / 1000`` (the colour is lost). ``timestamp`` in seconds.
``"webxr"`` (``XRLightEstimate``, WebXR Lighting Estimation)
    ``sphericalHarmonicsCoefficients``: 27 floats interleaved RGB, order
    ``C_0^0, C_1^-1, C_1^0, C_1^1, C_2^-2, ... C_2^2`` (spec); ``primaryLightDirection``
    *toward* the light and ``primaryLightIntensity`` RGB, both as ``{x, y, z, w}`` with
    w = 0 and 1. The spec does not fix the SH sign convention, so it is selectable
    (``shConvention`` in the file): ``"threejs"`` (default): the basis without the
    Condon-Shortley phase that three.js's ``XREstimatedLight`` feeds to
    ``SphericalHarmonics3`` and shades with ``shGetIrradianceAt``; ``"arcore"``: ARCore's
    CS-phase basis, which is what Chrome delivers, since its ARCore device copies
    ``ArLightEstimate_getEnvironmentalHdrAmbientSphericalHarmonics`` into the
    ``XRLightProbe`` unchanged (Chromium ``device/vr/android/arcore/arcore_impl.cc``,
    ``GetLightProbe``). The two differ in the sign of ``C_1^-1, C_1^1, C_2^-1, C_2^1``.
"""

from __future__ import annotations

import hashlib
import json
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from arlight.bounds import MAX_LIGHTS, MAX_SH_ORDER
from arlight.errors import InputError
from arlight.io.images import atomic_write
from arlight.light.extract import (
    ExtractedLight,
    highlight_regions,
    luminance,
    mean_luminance,
    median_cut,
)
from arlight.output_guard import record_written, written_by_arlight
from arlight.scene.schema import REQUIRED, Field, Validator
from arlight.sphere import sh as SH

LAYOUTS = ("arlight", "arcore", "arkit", "webxr")
METHODS = ("regions", "median_cut", "variance")
SH_CONVENTIONS = ("threejs", "arcore")  # webxr: whose SH signs (see the module docstring)
ARKIT_NEUTRAL_LUMENS = 1000.0  # SceneKit/ARKit: 1000 lm = "neutral" (light factor 1)
AUTO_THRESHOLD_FACTOR = 4.0  # default highlight threshold, x the mean luminance
FORMAT_TAG = "arlight.light_estimate"
MAX_VALUE = 1e20
"""Largest magnitude of a radiance/irradiance value or SH coefficient a light may hold (W/m^2,
W/(sr m^2)): beyond it a render overflows float32 to Inf."""

# ----------------------------------------------------------------------------- foreign SH


def _cartesian_l2_basis(condon_shortley: bool) -> Callable[[np.ndarray], np.ndarray]:
    """The common graphics L2 basis written in Cartesian world coordinates (z = pole)."""
    s = -1.0 if condon_shortley else 1.0
    k0, k1 = 0.5 / np.sqrt(np.pi), np.sqrt(3 / (4 * np.pi))  # 0.282095, 0.488603
    k2, k3, k4 = 0.5 * np.sqrt(15 / np.pi), 0.25 * np.sqrt(5 / np.pi), 0.25 * np.sqrt(15 / np.pi)

    def basis(d: np.ndarray) -> np.ndarray:
        x, y, z = d[:, 0], d[:, 1], d[:, 2]
        return np.stack([
            np.full_like(x, k0),
            s * k1 * y, k1 * z, s * k1 * x,
            k2 * x * y, s * k2 * y * z, k3 * (3 * z * z - 1),
            s * k2 * x * z, k4 * (x * x - y * y),
        ], axis=1)

    return basis


@lru_cache(maxsize=4)
def _to_foreign_matrix(condon_shortley: bool) -> np.ndarray:
    """``M`` with ``c_foreign = M @ c_ours`` (both L2): ``M_ji = int y^f_j y_i dw``."""
    dirs, w = SH.sphere_quadrature(4)
    Yf = _cartesian_l2_basis(condon_shortley)(dirs)
    Yo = SH.sh_basis(dirs, 2)
    M = (Yf * w[:, None]).T @ Yo
    M.setflags(write=False)
    return M


def _l2(coeffs: np.ndarray) -> np.ndarray:
    """Truncate or zero-pad radiance SH to 9 coefficients."""
    c = np.zeros((9, 3))
    k = min(9, coeffs.shape[0])
    c[:k] = coeffs[:k]
    return c


def sh_to_foreign(coeffs: np.ndarray, condon_shortley: bool) -> np.ndarray:
    """Our radiance SH (any order, truncated to L2) -> the Cartesian L2 basis, (9, 3)."""
    return _to_foreign_matrix(condon_shortley) @ _l2(np.asarray(coeffs, np.float64))


def sh_from_foreign(coeffs9: np.ndarray, condon_shortley: bool) -> np.ndarray:
    """Inverse of :func:`sh_to_foreign` (the matrix is orthogonal)."""
    return _to_foreign_matrix(condon_shortley).T @ np.asarray(coeffs9, np.float64)


def arcore_shader_factors() -> np.ndarray:
    """ARCore's hello_ar ``sphericalHarmonicFactors``: ``y_lm`` constant x ``A_l / pi``
    for the CS-phase Cartesian basis, so that ``sum_i f_i c_i p_i(n) = E(n) / pi``."""
    k = np.array([0.282095, -0.488603, 0.488603, -0.488603, 1.092548, -1.092548,
                  0.315392, -1.092548, 0.546274])
    A = np.array([SH.clamped_cosine_band(int(l)) for l in SH.band_of_each_coeff(2)])
    return k * A / np.pi


def _clip_band(threshold: float, keep: np.ndarray | None, lum: np.ndarray | None
               ) -> Callable[[int, int, np.ndarray], np.ndarray]:
    """A band function for :func:`arlight.sphere.sh.project_equirect`: rows ``[r0, r1)``
    clipped at luminance ``threshold`` (``L min(1, t / Y(L))``, the
    :func:`~arlight.light.extract.split_highlights` rule), except where ``keep`` is True
    (sources that stay in the remainder whole). ``lum``: the map's luminance plane when
    already computed (None: computed per band)."""

    def band(r0: int, r1: int, rows: np.ndarray) -> np.ndarray:
        y = luminance(rows) if lum is None else lum[r0:r1]
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(y > threshold, np.float32(threshold) / y, np.float32(1.0))
        if keep is not None:
            f[keep[r0:r1]] = 1.0
        return rows[..., :3] * f[..., None]

    return band


# ----------------------------------------------------------------------------- the type


def _vec3(v, name: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.size != 3 or not np.all(np.isfinite(a)):
        raise InputError(f"expected 3 finite numbers, got {v!r}", field=name)
    return a


@dataclass
class LightEstimate:
    """Main directional light + radiance SH of the rest (+ extra lights, HDR map).

    ``main_direction``: unit vector *toward* the main light (world, +Y up);
    ``main_irradiance``: RGB W/m^2 on a surface facing it; ``sh``: ``(n, 3)`` radiance SH
    (our basis) of the ambient remainder (neither the main nor the extra lights);
    ``lights``: further explicit lights; ``hdr_map``: ``(H, 2H, 3)`` equirect radiance of
    the whole environment (optional); ``timestamp`` in seconds; ``confidence`` in [0, 1]
    (for estimates from a capture: the fraction of the sphere actually observed).
    ``main_solid_angle`` (sr) and ``main_spread`` (rad, angular radius) give the main
    light's size for soft shadows; ``explicit_fraction`` is the share of the map's
    luminance energy ``int Y(L) dw`` held by the explicit lights (main + extra), None when
    not estimated from a map.
    """

    main_direction: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    main_irradiance: np.ndarray = field(default_factory=lambda: np.zeros(3))
    sh: np.ndarray = field(default_factory=lambda: np.zeros((9, 3)))
    lights: list[ExtractedLight] = field(default_factory=list)
    hdr_map: np.ndarray | None = None
    timestamp: float = 0.0
    confidence: float = 1.0
    main_solid_angle: float = 0.0
    main_spread: float = 0.0
    explicit_fraction: float | None = None

    def __post_init__(self) -> None:
        d = _vec3(self.main_direction, "main_direction")
        n = np.linalg.norm(d)
        if n == 0:
            d, n = np.array([0.0, 1.0, 0.0]), 1.0
        self.main_direction = d if abs(n - 1.0) < 1e-12 else d / n
        self.main_irradiance = _vec3(self.main_irradiance, "main_irradiance")
        if np.any(np.abs(self.main_irradiance) > MAX_VALUE):
            raise InputError(f"magnitude beyond {MAX_VALUE:g}", field="main_irradiance")
        c = np.asarray(self.sh, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 3:
            raise InputError(f"expected (n, 3) coefficients, got shape {c.shape}", field="sh")
        try:
            SH.order_of(c.shape[0])
        except InputError as exc:
            raise InputError(exc.message, field="sh.coefficients") from exc
        if not np.all(np.isfinite(c)):
            raise InputError(f"{int(np.count_nonzero(~np.isfinite(c)))} coefficients are "
                             "not finite (NaN/Inf)", field="sh.coefficients")
        if np.any(np.abs(c) > MAX_VALUE):
            raise InputError(f"a coefficient's magnitude is beyond {MAX_VALUE:g}",
                             field="sh.coefficients")
        self.sh = c
        self.timestamp = float(self.timestamp)
        if not np.isfinite(self.timestamp):
            raise InputError(f"must be a finite number, got {self.timestamp}", field="timestamp")
        self.confidence = float(self.confidence)
        if not 0.0 <= self.confidence <= 1.0:
            raise InputError(f"must be in [0, 1], got {self.confidence}", field="confidence")
        self.main_solid_angle = float(self.main_solid_angle)
        self.main_spread = float(self.main_spread)
        for name in ("main_solid_angle", "main_spread"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"must be a finite number >= 0, got {v}", field=name)
        if self.explicit_fraction is not None:
            self.explicit_fraction = float(self.explicit_fraction)
            if not 0.0 <= self.explicit_fraction <= 1.0 + 1e-9:
                raise InputError(f"must be in [0, 1], got {self.explicit_fraction}",
                                 field="explicit_fraction")
        if self.hdr_map is not None:
            self.hdr_map = np.asarray(self.hdr_map, dtype=np.float32)

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_envmap(cls, equirect: np.ndarray, n_lights: int = 16, sh_order: int = 2,
                    method: str = "regions", threshold: float | None = None,
                    keep_map: bool = True, timestamp: float | None = None,
                    confidence: float = 1.0, sh_map: np.ndarray | None = None,
                    gap_deg: float = 1.0) -> LightEstimate:
        """Estimate from an equirect radiance map ``(H, 2H, 3)``.

        Pixels above ``threshold`` (luminance; default 4 x the mean) hold the light
        sources. ``method="regions"`` (default): each connected highlight region on the
        sphere is one light (:func:`~arlight.light.extract.highlight_regions`; the number
        adapts to the map, ``n_lights`` is the cap, ``gap_deg`` merges near fragments), so
        the main light is the most energetic *source* with all of its energy and its size.
        ``"median_cut"``/``"variance"``: the above-threshold part is cut into ``n_lights``
        regions of the image (Debevec 2005 / Viriyothai & Debevec 2009). The part of the
        map below the threshold (and of sources not made lights) is projected to SH of
        ``sh_order``. With ``n_lights = 0`` everything goes to SH and the main light is the
        SH's dominant direction with zero irradiance.

        ``sh_map`` (default: ``equirect``) is the map whose remainder goes to SH, e.g. a
        fisheye capture with the upper hemisphere mirrored into the lower one, while the
        lights come from the observed ``equirect`` only (mirrored lamps would otherwise
        pull light directions to the horizon; their copies are clipped, not lights).

        Each step runs once per map: one float32 luminance plane, sparse highlight pixels,
        and the SH of the clipped remainder is projected band by band without building it.
        """
        if method not in METHODS:
            raise ValueError(f"unknown extraction method {method!r}; use one of "
                             f"{', '.join(METHODS)}")
        img = np.asarray(equirect, dtype=np.float32)
        full = img if sh_map is None else np.asarray(sh_map, dtype=np.float32)
        lum = luminance(img)
        mean = mean_luminance(lum)
        total = 4 * np.pi * mean  # int Y(L) dw of the observed map
        lights: list[ExtractedLight] = []
        thr = AUTO_THRESHOLD_FACTOR * mean if threshold is None else float(threshold)
        dropped = None
        if n_lights > 0:
            if method == "regions":
                found = highlight_regions(img, thr, lum=lum, max_lights=n_lights,
                                          gap_deg=gap_deg)
                lights, dropped = found.lights, found.dropped
            else:
                rest_of_img = _clip_band(thr, None, lum)(0, img.shape[0], img)
                bright = img - rest_of_img
                del rest_of_img
                cand = median_cut(bright, n_lights, method=method)
                del bright
                tot = sum(float(lt.irradiance @ SH.LUMINANCE) for lt in cand)
                lights = [lt for lt in cand if float(lt.irradiance @ SH.LUMINANCE) > 1e-9 * tot]
        if full is not img:
            lum = None  # the SH bands compute the luminance of sh_map's rows themselves
        band = _clip_band(thr, dropped, lum) if n_lights > 0 else None
        coeffs = SH.project_equirect(full, sh_order, band=band)
        del band, lum
        held = sum(float(lt.irradiance @ SH.LUMINANCE) for lt in lights)
        fraction = min(1.0, held / total) if total > 0 else 0.0
        if lights:
            main, extra = lights[0], lights[1:]
            kw = {"main_direction": main.direction, "main_irradiance": main.irradiance,
                  "main_solid_angle": main.solid_angle, "main_spread": main.spread}
        else:
            extra = []
            kw = {"main_direction": SH.dominant_direction(coeffs),
                  "main_irradiance": np.zeros(3)}
        return cls(sh=coeffs, lights=extra, hdr_map=full if keep_map else None,
                   timestamp=time.time() if timestamp is None else timestamp,
                   confidence=confidence, explicit_fraction=fraction, **kw)

    # ------------------------------------------------------------------ queries

    def ambient_sh(self, order: int = 2, fold_lights: bool = True) -> np.ndarray:
        """Radiance SH of everything except the main light; ``fold_lights`` adds the extra
        lights as delta lobes (what ARCore-style "ambient" SH mean)."""
        c = np.zeros((SH.n_coeffs(order), 3))
        k = min(c.shape[0], self.sh.shape[0])
        c[:k] = self.sh[:k]
        if fold_lights:
            for lt in self.lights:
                c += SH.directional_light_coeffs(lt.direction, lt.irradiance, order)
        return c

    def total_sh(self, order: int = 2) -> np.ndarray:
        """Radiance SH of the whole environment (main and extra lights folded in)."""
        return self.ambient_sh(order) + SH.directional_light_coeffs(
            self.main_direction, self.main_irradiance, order)

    def explicit_lights(self) -> list[ExtractedLight]:
        """The main light followed by the extra lights (the main one may have zero
        irradiance: an estimate whose light is all in the SH)."""
        return [ExtractedLight(self.main_direction, self.main_irradiance), *self.lights]

    def irradiance(self, normals: np.ndarray) -> np.ndarray:
        """Irradiance (W/m^2) at unit normals: 9-coefficient SH of the ambient part plus the
        explicit lights with their exact clamped cosine."""
        n = np.asarray(normals, np.float64).reshape(-1, 3)
        E = SH.irradiance(self.sh, n)
        for lt in self.explicit_lights():
            E += np.clip(n @ lt.direction, 0, None)[:, None] * lt.irradiance[None]
        return E

    # ------------------------------------------------------------------ scene files

    def to_scene_lights(self, light_type: str = "directional", room_size: float = 2.0,
                        origin: np.ndarray | None = None, include_extra: bool = True,
                        include_sh: bool = True, envmap_file: str | None = None,
                        envmap_scale: float = 1.0) -> list[dict]:
        """Light tables for an AR scene file (schema of ``arlight.scene``).

        ``light_type``: ``"directional"`` (``irradiance``) or ``"point"`` at
        ``origin + direction * room_size`` (Kan's room size) with ``I = E room_size^2``.
        The SH remainder becomes one ``{"type": "sh"}`` table. With ``envmap_file`` (an EXR
        of :attr:`hdr_map`, written by the caller, e.g. :meth:`write_hdr_map`) a single
        ``envmap`` table is returned instead: the map already holds every light, so adding
        lights would count them twice.
        """
        if envmap_file is not None:
            return [{"type": "envmap", "file": str(envmap_file), "mapping": "equirect",
                     "scale": float(envmap_scale), "rotation_deg": 0.0}]
        if light_type not in ("directional", "point"):
            raise ValueError(f"light_type must be 'directional' or 'point', got {light_type!r}")
        lights = self.explicit_lights() if include_extra else self.explicit_lights()[:1]
        out: list[dict] = []
        for lt in lights:
            if not np.any(lt.irradiance > 0):
                continue
            out.append(lt.to_directional() if light_type == "directional"
                       else lt.to_point(room_size, origin))
        if include_sh:
            sh = self.sh if include_extra else self.ambient_sh(SH.order_of(self.sh.shape[0]))
            out.append({"type": "sh", "coefficients": sh.tolist()})
        return out

    def write_hdr_map(self, path: str | Path) -> Path:
        """Write :attr:`hdr_map` as an EXR (atomic).

        A map read by :func:`arlight.io.images.read_hdr` lives in a Mitsuba bitmap; that
        bitmap is written directly, so a 4k map is not copied once more to be written."""
        from arlight.io.images import atomic_write, write_exr

        if self.hdr_map is None:
            raise ValueError("this estimate has no HDR map")
        bitmap = _own_bitmap(self.hdr_map)
        if bitmap is None:
            return write_exr(path, self.hdr_map)
        with atomic_write(path, ".exr") as tmp:
            bitmap.write(str(tmp))
        return Path(path)

    # ------------------------------------------------------------------ JSON

    def to_json(self, layout: str = "arlight", hdr_file: str | None = None,
                sh_convention: str = "threejs") -> dict:
        """A JSON-ready dict in ``layout`` (see the module docstring); ``sh_convention``
        (``"threejs"`` or ``"arcore"``) picks the SH signs of the ``webxr`` layout."""
        if sh_convention not in SH_CONVENTIONS:
            raise ValueError(f"unknown SH convention {sh_convention!r}; expected one of "
                             f"{SH_CONVENTIONS}")
        if layout == "arlight":
            d = {
                "format": FORMAT_TAG, "version": 1,
                "main_light": {"direction_to_light": self.main_direction.tolist(),
                               "irradiance": self.main_irradiance.tolist(),
                               "solid_angle": self.main_solid_angle,
                               "spread": self.main_spread},
                "sh": {"order": SH.order_of(self.sh.shape[0]), "quantity": "radiance",
                       "basis": "arlight (docs/conventions.md, Franke Eq. 4.5)",
                       "coefficients": self.sh.tolist()},
                "lights": [lt.to_dict() for lt in self.lights],
                "timestamp": self.timestamp, "confidence": self.confidence,
            }
            if self.explicit_fraction is not None:
                d["explicit_energy_fraction"] = self.explicit_fraction
            if hdr_file is not None:
                d["hdr_map"] = {"file": hdr_file, "mapping": "equirect"}
            return d
        amb = self.ambient_sh(2)
        if layout == "arcore":
            c = sh_to_foreign(amb, condon_shortley=True)
            return {"layout": "arcore",
                    "environmentalHdrAmbientSphericalHarmonics": c.reshape(-1).tolist(),
                    "environmentalHdrMainLightDirection": self.main_direction.tolist(),
                    "environmentalHdrMainLightIntensity": self.main_irradiance.tolist(),
                    "timestamp": int(round(self.timestamp * 1e9)), "state": "VALID",
                    "confidence": self.confidence}
        if layout == "arkit":
            c = sh_to_foreign(amb, condon_shortley=False)
            return {"layout": "arkit",
                    "sphericalHarmonicsCoefficients": c.T.reshape(-1).tolist(),
                    "primaryLightDirection": (-self.main_direction).tolist(),
                    "primaryLightIntensity": ARKIT_NEUTRAL_LUMENS * float(
                        self.main_irradiance @ SH.LUMINANCE) / np.pi,
                    "timestamp": self.timestamp, "confidence": self.confidence}
        if layout == "webxr":
            c = sh_to_foreign(amb, condon_shortley=sh_convention == "arcore")
            x, y, z = self.main_direction
            r, g, b = self.main_irradiance
            return {"layout": "webxr", "shConvention": sh_convention,
                    "sphericalHarmonicsCoefficients": c.reshape(-1).tolist(),
                    "primaryLightDirection": {"x": x, "y": y, "z": z, "w": 0.0},
                    "primaryLightIntensity": {"x": r, "y": g, "z": b, "w": 1.0},
                    "timestamp": self.timestamp, "confidence": self.confidence}
        raise ValueError(f"unknown layout {layout!r}; expected one of {LAYOUTS}")

    @staticmethod
    def detect_layout(d: dict) -> str:
        """Guess the layout of a JSON dict (``"layout"``/``"format"`` keys, else the keys)."""
        if d.get("format") == FORMAT_TAG:
            return "arlight"
        if d.get("layout") in LAYOUTS:
            return str(d["layout"])
        if "environmentalHdrAmbientSphericalHarmonics" in d:
            return "arcore"
        if "sphericalHarmonicsCoefficients" in d:
            return "arkit" if np.isscalar(d.get("primaryLightIntensity", 0.0)) else "webxr"
        raise InputError("not a light estimate: no known layout keys")

    @classmethod
    def from_json(cls, d: dict, layout: str | None = None,
                  base_dir: str | Path | None = None, file: str | None = None
                  ) -> LightEstimate:
        """Parse a dict written by :meth:`to_json` (or by ARCore/ARKit/WebXR apps) through the
        schema :class:`~arlight.scene.schema.Validator` (the tables :data:`LAYOUT_FIELDS`).
        Raises :class:`~arlight.errors.InputError` naming ``file`` and the field; unknown
        keys are errors (as in scene files), and so are values of the wrong type, NaN/Inf
        numbers and missing required fields."""
        v = Validator(file, Path(base_dir) if base_dir is not None else Path("."))
        layout = layout or cls.detect_layout(d)
        if layout not in LAYOUTS:
            raise v.fail("layout", f"unknown layout {layout!r}; expected one of "
                         f"{', '.join(LAYOUTS)}")
        try:
            return cls._from_json(v.fields(v.table(d, ""), LAYOUT_FIELDS[layout], ""), layout,
                                  v, base_dir)
        except InputError as exc:
            if exc.file is None and file is not None:  # the checks of __post_init__
                raise InputError(exc.message, file=file, field=exc.field) from exc
            raise

    @classmethod
    def _from_json(cls, d: dict, layout: str, v: Validator, base_dir: str | Path | None
                   ) -> LightEstimate:
        """``d``: the top-level fields, validated; the nested tables are validated here."""
        if layout == "arlight":
            ml = _fields(v, d["main_light"], _MAIN_LIGHT, "main_light")
            sh = v.table(d["sh"], "sh")
            coeffs = sh.get("coefficients")
            if isinstance(coeffs, list) and len(coeffs) > (MAX_SH_ORDER + 1) ** 2:
                raise v.fail("sh.coefficients", f"{len(coeffs)} coefficients: more than SH "
                             f"order {MAX_SH_ORDER} ({(MAX_SH_ORDER + 1) ** 2})")
            sh = _fields(v, sh, _SH_TABLE, "sh")
            lights = d["lights"]
            if not isinstance(lights, list):
                raise v.fail("lights", "expected a list of light tables, got "
                             f"{type(lights).__name__}")
            if len(lights) > MAX_LIGHTS:
                raise v.fail("lights", f"{len(lights)} lights; at most {MAX_LIGHTS}")
            lights = [_fields(v, lt, _LIGHT, f"lights[{i}]") for i, lt in enumerate(lights)]
            hdr = None
            if d["hdr_map"] is not None:
                fields = v.fields(v.table(d["hdr_map"], "hdr_map"), _HDR_MAP, "hdr_map")
                if base_dir is not None:
                    from arlight.io.images import read_linear

                    try:
                        hdr = read_linear(Path(base_dir) / fields["file"])
                    except InputError as exc:  # the map it references: name both files
                        raise v.fail("hdr_map.file", f"{exc.file}: {exc.message}"
                                     if exc.file else exc.message) from exc
            return cls(main_direction=ml["direction_to_light"],
                       main_irradiance=ml["irradiance"], main_solid_angle=ml["solid_angle"],
                       main_spread=ml["spread"],
                       explicit_fraction=d["explicit_energy_fraction"],
                       sh=np.asarray(sh["coefficients"], np.float64),
                       lights=[ExtractedLight.from_dict(lt) for lt in lights],
                       hdr_map=hdr, timestamp=d["timestamp"], confidence=d["confidence"])
        if layout == "arcore":
            key = "environmentalHdrAmbientSphericalHarmonics"
            c = np.array(v.vector(d[key], 27, key)).reshape(9, 3)
            return cls(main_direction=d["environmentalHdrMainLightDirection"],
                       main_irradiance=d["environmentalHdrMainLightIntensity"],
                       sh=sh_from_foreign(c, condon_shortley=True),
                       timestamp=d["timestamp"] * 1e-9, confidence=d["confidence"])
        key = "sphericalHarmonicsCoefficients"
        if layout == "arkit":
            c = np.array(v.vector(d[key], 27, key)).reshape(3, 9).T
            inten = d["primaryLightIntensity"]
            return cls(main_direction=-np.asarray(d["primaryLightDirection"]),
                       main_irradiance=np.full(3, np.pi * inten / ARKIT_NEUTRAL_LUMENS),
                       sh=sh_from_foreign(c, condon_shortley=False),
                       timestamp=d["timestamp"], confidence=d["confidence"])
        c = np.array(v.vector(d[key], 27, key)).reshape(9, 3)  # webxr
        return cls(main_direction=_point(v, d["primaryLightDirection"], "primaryLightDirection"),
                   main_irradiance=_point(v, d["primaryLightIntensity"], "primaryLightIntensity"),
                   sh=sh_from_foreign(c, condon_shortley=d["shConvention"] == "arcore"),
                   timestamp=d["timestamp"], confidence=d["confidence"])

    def save(self, path: str | Path, layout: str = "arlight",
             protect: tuple[str | Path, ...] = (), sh_convention: str = "threejs") -> Path:
        """Write JSON atomically; with ``layout="arlight"`` and an HDR map, the map goes to
        ``<stem>.<hash>.hdr.exr`` next to it (referenced relatively; ``<hash>``: 8 hex digits
        of the map's content, hashed in place). ``sh_convention``: see :meth:`to_json`.

        The pair is replaced as one set: the map is written first under its content-named
        file, the JSON (which names it) replaces the old one in one rename, and only then is
        the map of the previous JSON removed — a reader sees the old pair or the new one,
        never a mix. Maps left by an interrupted save (named like ours, referenced by no
        JSON) are removed by the next save. Both files are recorded in the folder's ledger
        (:func:`arlight.output_guard.record_written`); only recorded, unchanged maps are ever
        removed, never a file a person made. ``protect``: files that must not be overwritten
        or removed (the inputs); a clash raises ValueError before anything is written.
        """
        path = Path(path)
        guarded = [Path(p) for p in protect]
        _refuse_clash(path, guarded)
        previous = _referenced_map(path)
        hdr_file = None
        if layout == "arlight" and self.hdr_map is not None:
            digest = hashlib.sha256(memoryview(np.ascontiguousarray(self.hdr_map)).cast("B"))
            hdr_file = f"{path.stem}.{digest.hexdigest()[:8]}.hdr.exr"
            _refuse_clash(path.parent / hdr_file, guarded)
            self.write_hdr_map(path.parent / hdr_file)
            record_written([path.parent / hdr_file])  # a leftover of a killed save is ours
        text = json.dumps(self.to_json(layout, hdr_file=hdr_file,
                                       sh_convention=sh_convention), indent=1)
        with atomic_write(path, ".json") as tmp:
            tmp.write_text(text)
        record_written([path])
        for old in _side_maps(path):  # the previous pair's map and leftovers of killed saves
            if old.name != hdr_file and not any(_same(old, g) for g in guarded) and (
                    old.name == previous or _SIDE_MAP.fullmatch(old.name[len(path.stem):])
            ) and written_by_arlight(old):  # never a file a person made
                old.unlink(missing_ok=True)
        return Path(path)

    @classmethod
    def load(cls, path: str | Path, layout: str | None = None) -> LightEstimate:
        """Read a light JSON. Raises :class:`InputError` naming the file and the field."""
        path = Path(path)
        return cls.from_json(read_json(path), layout, base_dir=path.parent, file=str(path))


def read_json(path: Path) -> dict:
    """The JSON object in ``path`` (a light file), or an :class:`InputError` naming it."""
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise InputError("file not found", file=str(path)) from exc
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", file=str(path)) from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", file=str(path)) from exc
    if not isinstance(d, dict):
        raise InputError("expected a JSON object", file=str(path))
    return d


_CONFIDENCE = Field("float", 1.0, "observed fraction of the sphere", min=0.0, max=1.0)
_SH27 = Field("table", REQUIRED, "27 floats (9 RGB coefficients, the layout's order)")
LAYOUT_FIELDS: dict[str, dict[str, Field]] = {
    "arlight": {
        "format": Field("str", None, f"`{FORMAT_TAG}`"),
        "version": Field("int", 1, "format version"),
        "main_light": Field("table", REQUIRED, "the main light (below)"),
        "sh": Field("table", REQUIRED, "radiance SH of the remainder (below)"),
        "lights": Field("table", [], "further explicit lights (below)"),
        "hdr_map": Field("table", None, "the HDR map next to the JSON (below)"),
        "timestamp": Field("float", 0.0, "capture time", "s"),
        "confidence": _CONFIDENCE,
        "explicit_energy_fraction": Field("float", None, "share of the map's energy in the "
                                          "explicit lights", min=0.0, max=1.0 + 1e-9),
    },
    "arcore": {
        "layout": Field("str", None),
        "environmentalHdrAmbientSphericalHarmonics": _SH27,
        "environmentalHdrMainLightDirection": Field("vec3", REQUIRED, "toward the light"),
        "environmentalHdrMainLightIntensity": Field("vec3", REQUIRED, "RGB irradiance"),
        "timestamp": Field("float", 0.0, "capture time", "ns"),
        "state": Field("str", None),
        "confidence": _CONFIDENCE,
    },
    "arkit": {
        "layout": Field("str", None),
        "sphericalHarmonicsCoefficients": _SH27,
        "primaryLightDirection": Field("vec3", REQUIRED, "the direction the light travels"),
        "primaryLightIntensity": Field("float", 0.0, "SceneKit lumens"),
        "timestamp": Field("float", 0.0, "capture time", "s"),
        "confidence": _CONFIDENCE,
    },
    "webxr": {
        "layout": Field("str", None),
        "shConvention": Field("choice", "threejs", choices=SH_CONVENTIONS),
        "sphericalHarmonicsCoefficients": _SH27,
        "primaryLightDirection": Field("table", REQUIRED, "{x, y, z, w}, toward the light"),
        "primaryLightIntensity": Field("table", REQUIRED, "{x, y, z, w}, RGB irradiance"),
        "timestamp": Field("float", 0.0, "capture time", "s"),
        "confidence": _CONFIDENCE,
    },
}
"""The top-level fields of each JSON layout (read by the schema's ``Validator``)."""
_IRRADIANCE = Field("vec3", REQUIRED, "RGB irradiance on a surface facing the light", "W/m²",
                    min=0.0, max=MAX_VALUE)
_MAIN_LIGHT = {"direction_to_light": Field("vec3", REQUIRED, "toward the light"),
               "irradiance": _IRRADIANCE,
               "solid_angle": Field("float", 0.0, "", "sr", min=0.0),
               "spread": Field("float", 0.0, "angular radius", "rad", min=0.0)}
_LIGHT = {"direction": Field("vec3", REQUIRED, "toward the light"), "irradiance": _IRRADIANCE,
          "solid_angle": Field("float", 0.0, "", "sr", min=0.0),
          "spread": Field("float", 0.0, "angular radius", "rad", min=0.0)}
_SH_TABLE = {"order": Field("int", None), "quantity": Field("str", None),
             "basis": Field("str", None),
             "coefficients": Field("rgb_list", REQUIRED, "(L+1)² RGB rows")}
_HDR_MAP = {"file": Field("str", REQUIRED, "EXR next to the JSON"),
            "mapping": Field("choice", "equirect", choices=("equirect",))}
_SIDE_MAP = re.compile(r"\.[0-9a-f]{8}\.hdr\.exr")


def hdr_map_path(d: dict, base_dir: str | Path) -> Path:
    """The HDR map file an ``arlight`` layout light names (relative to its folder)."""
    name = d["hdr_map"]["file"]
    if not isinstance(name, str) or not name:
        raise InputError(f"expected a file name, got {name!r}", field="hdr_map.file")
    return Path(base_dir) / name


def _own_bitmap(image: np.ndarray):
    """The Mitsuba RGB float32 bitmap whose whole memory ``image`` is, or None."""
    base = getattr(image, "base", None)
    if base is None or type(base).__name__ != "Bitmap" or not image.flags["C_CONTIGUOUS"]:
        return None
    import mitsuba as mi

    ok = (isinstance(base, mi.Bitmap) and base.pixel_format() == mi.Bitmap.PixelFormat.RGB
          and base.component_format() == mi.Struct.Type.Float32
          and tuple(base.size()) == (image.shape[1], image.shape[0]) and image.ndim == 3
          and image.shape[2] == 3 and image.dtype == np.float32
          and np.asarray(base).__array_interface__["data"][0]
          == image.__array_interface__["data"][0])
    return base if ok else None


def _same(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and a.samefile(b)
    except OSError:
        return False


def _refuse_clash(target: Path, protected: list[Path]) -> None:
    for p in protected:
        if _same(target, p) or Path(target).resolve() == Path(p).resolve():
            raise InputError(f"would overwrite the input {p}; choose another --output",
                             file=str(target), field="--output")


def _referenced_map(path: Path) -> str | None:
    """The map file named by the JSON at ``path`` (None when unreadable or absent)."""
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
        name = d["hdr_map"]["file"]
        return name if isinstance(name, str) and "/" not in name else None
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _side_maps(path: Path) -> list[Path]:
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        return []
    return [p for p in parent.iterdir() if p.name.startswith(f"{path.stem}.")
            and p.name.endswith(".hdr.exr") and p.is_file()]


_ELEMENT = re.compile(r"(.*?)((?:\[\d+\])+)")


def _fields(v: Validator, table, specs: dict[str, Field], field: str) -> dict:
    """``v.fields`` of a nested table; an error inside a vector or a coefficient list names
    the vector's field (``sh.coefficients``, ``main_light.irradiance``) and the element in the
    message, as the light files' errors always have."""
    try:
        return v.fields(v.table(table, field), specs, field)
    except InputError as exc:
        m = _ELEMENT.fullmatch(exc.field or "")
        if m is None or not m.group(1).startswith(f"{field}."):
            raise
        raise InputError(f"{exc.message} (element {m.group(2)})", file=exc.file,
                         field=m.group(1)) from exc


def _point(v: Validator, p, field: str) -> list[float]:
    """A WebXR ``{x, y, z, w}`` point (or a list of 3 or 4 numbers) -> ``[x, y, z]``."""
    if isinstance(p, dict):
        xyzw = {k: Field("float", REQUIRED if k != "w" else None) for k in "xyzw"}
        q = v.fields(p, xyzw, field)
        return [q["x"], q["y"], q["z"]]
    n = 4 if isinstance(p, list | tuple) and len(p) == 4 else 3
    return v.vector(p, n, field)[:3]


__all__ = ["ARKIT_NEUTRAL_LUMENS", "LAYOUTS", "METHODS", "SH_CONVENTIONS", "LightEstimate",
           "arcore_shader_factors", "sh_from_foreign", "sh_to_foreign"]
