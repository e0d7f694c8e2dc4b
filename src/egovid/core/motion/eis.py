"""Was the picture stabilised in the camera? The share of the body gyro's shake the picture keeps.

A camera with electronic image stabilisation (EIS: GoPro HyperSmooth, phones) counter-rotates
the picture inside the sensor, so its body gyro describes a shake the picture no longer has.
A stabiliser that trusts that gyro "removes" what is not there and so adds it. Files usually
say so (GoPro ``EISE``/``EISA``, see :attr:`~egovid.core.camera.telemetry.CameraTelemetry.
electronically_stabilized`); a re-muxed file loses the tag, and then it is measured here from
the picture: once the gyro is synced to the video (:func:`egovid.core.motion.gyro.sync_gyro`),
vision's angular rate between frames is compared with the gyro's over the same frame steps.

The measure is the Welch cross-spectral gain ``|P_vg(f)| / P_gg(f)`` of vision's rate ``v`` over
the gyro's ``g``, per camera axis, in the shake band :data:`BAND_HZ` (2-8 Hz), averaged with the
gyro's power as the weight: ``share = Σ_axes Σ_band |P_vg| / Σ_axes Σ_band P_gg``. It is 1 when
the picture turns as the body does and about the stabiliser's gain when the camera filtered it;
noise of vision that is uncorrelated with the gyro averages out of the cross-spectrum (only its
magnitude leaks in, by about ``sqrt(P_vv / P_gg / segments)``), and the modulus leaves a small
residual time offset of the sync (a phase) out of it.

Decision (:func:`verdict`): a share below :data:`MAX_SHARE` (0.5) with enough shake to judge
(gyro RMS rate in the band at least :data:`MIN_GYRO_RMS_DEG_S`) and vision measuring at least
:data:`MIN_MEASURED` of the steps means the camera stabilised the picture. Why 0.5: a focal-length
error scales vision's rates (a 10 % error moves the share by 0.1), and vision's noise and rolling
shutter move it by tenths; a factor 2 would need the focal length off by half, while EIS keeps a
few tenths of the shake at most.

Rates in radians per second in, degrees per second out; frequencies in hertz.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The shake band (Hz): above intentional motion (walking, panning), below the frame rate's limit.
BAND_HZ = (2.0, 8.0)
#: A picture keeping less than this share of the gyro's shake was stabilised in the camera.
MAX_SHARE = 0.5
#: Gyro RMS rate (deg/s) in the band below which there is too little shake to judge.
MIN_GYRO_RMS_DEG_S = 2.0
#: Share of the frame steps vision must have measured itself (not bridged) to judge.
MIN_MEASURED = 0.9
#: Welch segment length in seconds (frequency resolution about 1 / this).
SEGMENT_S = 2.0

STABILISED = "stabilised in camera"
KEPT = "picture follows the gyro"
CANNOT_TELL = "cannot tell"


@dataclass(frozen=True)
class PictureShare:
    """How much of the body gyro's shake the picture keeps.

    ``share``: power-weighted cross-spectral gain of vision over the gyro in the band (NaN when
    the band holds no gyro motion or no frequency bin); ``gyro_rms_deg_s``: the gyro's RMS rate
    in the band (deg/s, all axes); ``measured``: share of the frame steps vision measured itself;
    ``verdict``: :data:`STABILISED`, :data:`KEPT` or :data:`CANNOT_TELL`.
    """

    share: float
    gyro_rms_deg_s: float
    measured: float
    verdict: str

    @property
    def stabilised(self) -> bool:
        """True when the picture was judged stabilised in the camera."""
        return self.verdict == STABILISED

    def to_dict(self) -> dict:
        """JSON-ready (rounded; a NaN share is null)."""
        return {
            "share": round(self.share, 3) if np.isfinite(self.share) else None,
            "gyro_rms_deg_s": round(self.gyro_rms_deg_s, 3),
            "measured": round(self.measured, 3),
            "verdict": self.verdict,
        }

    def describe(self) -> str:
        """In words, for a reason: what share of the shake the picture keeps."""
        share = f"{100 * self.share:.0f} %" if np.isfinite(self.share) else "an unknown share"
        return (
            f"the picture keeps {share} of the body gyro's {BAND_HZ[0]:g}-{BAND_HZ[1]:g} Hz shake "
            f"({self.gyro_rms_deg_s:.2f} deg/s RMS, {100 * self.measured:.0f} % of steps measured)"
        )


def band_gain(
    vision_rates: np.ndarray, gyro_rates: np.ndarray, fps: float, band: tuple[float, float] = BAND_HZ
) -> tuple[float, float]:
    """Share of the gyro's band motion the picture keeps, and the gyro's band RMS rate (deg/s).

    ``vision_rates``, ``gyro_rates`` (N, 3) rad/s over the same frame steps in the same (camera)
    axes, ``fps`` the steps per second. Welch with Hann segments of :data:`SEGMENT_S` seconds (at
    most a third of the series, at least 16 steps), half overlapping, mean removed per segment.
    Returns ``(share, rms)``; share is NaN without a bin in the band or without gyro power there.
    """
    v = np.degrees(np.asarray(vision_rates, float))
    g = np.degrees(np.asarray(gyro_rates, float))
    if v.shape != g.shape or v.ndim != 2 or len(v) < 16 or fps <= 0:
        return float("nan"), 0.0
    nperseg = int(max(16, min(round(SEGMENT_S * fps), len(v) // 3)))
    nperseg = min(nperseg, len(v))
    from scipy import signal  # ~1 s to import: not at import, which every command start would pay

    f, p_gg = signal.welch(g, fs=fps, nperseg=nperseg, axis=0)
    _, p_vg = signal.csd(v, g, fs=fps, nperseg=nperseg, axis=0)
    inband = (f >= band[0]) & (f <= min(band[1], 0.5 * fps))
    if not np.any(inband):
        return float("nan"), 0.0
    df = float(f[1] - f[0])
    power = float(np.sum(p_gg[inband]))
    rms = float(np.sqrt(power * df))
    share = float(np.sum(np.abs(p_vg[inband])) / power) if power > 0 else float("nan")
    return share, rms


def verdict(share: float, gyro_rms_deg_s: float, measured: float) -> str:
    """:data:`STABILISED` when the picture keeps under :data:`MAX_SHARE` of a shake of at least
    :data:`MIN_GYRO_RMS_DEG_S` with at least :data:`MIN_MEASURED` of the steps measured;
    :data:`KEPT` when it keeps at least :data:`MAX_SHARE`; else :data:`CANNOT_TELL`."""
    if not np.isfinite(share) or gyro_rms_deg_s < MIN_GYRO_RMS_DEG_S or measured < MIN_MEASURED:
        return CANNOT_TELL
    return STABILISED if share < MAX_SHARE else KEPT


def picture_share(
    vision_rates: np.ndarray, gyro_rates: np.ndarray, fps: float, measured: np.ndarray | None = None
) -> PictureShare:
    """:func:`band_gain` and :func:`verdict` of vision against the synced gyro.

    ``vision_rates``, ``gyro_rates`` (N, 3) rad/s per frame step in camera axes; ``fps`` steps per
    second; ``measured`` (N,) bool, the steps vision measured itself (all when None).
    """
    share, rms = band_gain(vision_rates, gyro_rates, fps)
    n = len(vision_rates)
    frac = float(np.mean(measured)) if measured is not None and n else (1.0 if n else 0.0)
    return PictureShare(share, rms, frac, verdict(share, rms, frac))
