"""Calibrated lens profiles (Gyroflow's CC0 database), looked up for a video.

egovid ships a compact index of the 9,779 usable profiles of Gyroflow's lens database
(``data/lens_profiles.json.gz``, built by ``experiments/build_lens_profiles.py``): for each, the
camera brand and model, the lens and setting words, the calibration size and frame rate, the
OpenCV fisheye camera matrix and distortion ``k1..k4`` and, where calibrated, the frame readout
time of the rolling shutter. :func:`find_profile` picks the profile of a video from what the file
says about itself:

* **camera**: brand and model, compared without case, spaces or punctuation and without a
  leading brand (``"Hero6 Black"`` = ``"HERO6 Black"``, ``"GoPro Max"`` = ``"Max"``); when the
  file names the brand, the profile's must be the same (:func:`camera_key`: ``"samsung"`` =
  ``"Samsung Electronics"``, a Redmi is a Xiaomi, a Samsung ``SM-G991B`` is its ``Galaxy S21``),
  so another maker's camera of the same model name is never taken;
* **phone camera** (``phone=True``, the make and model from the phone's own container keys): a
  phone has several cameras, and the one named by the file's lens words is taken (front,
  ultra wide, telephoto), else the main (wide) one: the profiles that say so, else those that say
  nothing, each only where its focal length is a main camera's (:data:`PHONE_MAIN_35MM`);
* **lens**: a GoPro lens mode (``W``, ``M``, ``N``, ``L``, ``S``, ``H``, ``X``; see
  :data:`LENS_CLASSES`) must be the profile's; a lens name (``"FE 24mm F1.4 GM"``) must share its
  words with the profile's lens; with no lens known, only a camera whose profiles all describe
  one field of view (within :data:`MAX_SPREAD`) matches;
* **stabilisation**: electronic stabilisation crops and warps the picture, so a profile recorded
  with it on (``HS EIS``, ``EIS-Y``, ``Boost``...) is not used for a video with it off, nor the
  other way round; a profile that does not say is used for either, after the ones that agree;
* **picture**: the same aspect ratio (within 1 %: a 4:3 mode is another crop of the sensor
  than 16:9), then the calibration at this very size (or one Gyroflow lists as compatible)
  before one to be scaled, then the nearest frame rate (high-speed modes crop differently),
  then Gyroflow's official profiles, then the lowest calibration error.

Profiles with a non-linear "digital lens" (GoPro SuperView and HyperView stretch) or an anamorphic
squeeze are never used: egovid's fisheye model does not describe them. Among the profiles that
tie on all of the above the medoid of the focal length is taken (community profiles of one mode
scatter), and a spread above :data:`MAX_SPREAD` is reported instead of guessed.

Everything is in pixels of the video (display orientation: the profile, calibrated on the
sensor's landscape picture, is turned by the container's rotation flag as the decoder turns the
frames, :meth:`~egovid.core.camera.intrinsics.Intrinsics.rotated`), the distortion is OpenCV's fisheye
model (``θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)``, ``r = f θd``), readout times in
milliseconds (negative: bottom row first).
"""

from __future__ import annotations

import functools
import gzip
import json
import math
import re
from dataclasses import dataclass
from importlib import resources

from egovid.core.camera.intrinsics import Intrinsics

#: Largest relative spread (max/min - 1) of the focal lengths of the profiles taken as one match.
MAX_SPREAD = 0.08
#: Largest relative difference of aspect ratios (width/height) between profile and video.
MAX_ASPECT_ERROR = 0.01

#: GoPro lens-mode codes (GPMF ``VFOV``) and the lens class they select among the profiles.
LENS_CLASSES = {
    "W": "wide",
    "M": "medium",
    "N": "narrow",
    "L": "linear",
    "R": "linear",  # Linear + horizon levelling: the same lens, the picture rotated
    "S": "superview",
    "H": "hyperview",
    "X": "max superview",
}

#: Words of the profiles' lens and setting text that name a lens class, tried in this order
#: (the first that matches wins; "max" alone depends on the camera, see :func:`lens_class`).
_LENS_WORDS = (
    ("anamorphic", r"anamor|anomor|squeeze"),
    ("max lens mod", r"max ?lens|maxlens|lens ?mod"),
    ("hyperview", r"hyper ?view"),
    ("max superview", r"max ?super ?view|\bmsv\b"),
    ("superview", r"super ?view|\bsuper\b"),
    ("linear", r"linear|\blin\b"),
    ("medium", r"medium|\bmid\b"),
    ("narrow", r"narrow"),
    ("max wide", r"max ?wide"),
    ("wide", r"wide|gran ?angular|\bww\b|超宽"),
    ("max", r"\bmax\b"),
)
#: Makers' names that are another spelling of a brand (normalised: lower case, letters and digits).
BRAND_ALIASES = {
    "samsungelectronics": "samsung",
    "lge": "lg",
    "lgelectronics": "lg",
    "hmdglobal": "nokia",
    "asustek": "asus",
    "asustekcomputerinc": "asus",
    "xiaomipoco": "poco",
    "huaweitechnologies": "huawei",
    "sonymobile": "sony",
    "oneplustechnology": "oneplus",
    "blackmagicdesign": "blackmagic",
}
#: Sub-brands and the maker that writes its name into their files (a Redmi phone says "Xiaomi").
SUB_BRANDS = {"redmi": "xiaomi", "poco": "xiaomi"}
#: Series words a maker's own model names may or may not carry (``"Galaxy S21"`` = ``"S21"``).
SERIES_WORDS = {"samsung": ("galaxy",)}
#: Samsung's model codes (as Android writes them: ``SM-G991B``; letter and three digits) of the
#: phones the database holds by name (public model lists; the region suffix does not matter).
SAMSUNG_CODES = {
    "g960": "S9", "g965": "S9+", "g970": "S10e", "g973": "S10", "g975": "S10+", "g977": "S10 5G",
    "g980": "S20", "g981": "S20", "g985": "S20+", "g986": "S20+", "g988": "S20 Ultra",
    "g780": "S20 FE", "g781": "S20 FE", "g990": "S21 FE", "g991": "S21", "g996": "S21+",
    "g998": "S21 Ultra", "s901": "S22", "s906": "S22+", "s908": "S22 Ultra", "s911": "S23",
    "s916": "S23+", "s918": "S23 Ultra", "s711": "S23 FE", "s921": "S24", "s926": "S24+",
    "s928": "S24 Ultra", "n960": "Note9", "n970": "Note10", "n975": "Note10+", "n980": "Note20",
    "n981": "Note20", "n985": "Note20 Ultra", "n986": "Note20 Ultra", "a515": "A51", "a525": "A52",
    "a526": "A52 5G", "a528": "A52s", "a536": "A53", "a546": "A54", "a715": "A71", "a725": "A72",
}  # fmt: skip
#: Range of 35 mm-equivalent focal lengths (mm, on the picture's diagonal) of a phone's main
#: camera in video: the database's phone profiles that name their lens put the main camera's
#: middle 80 % at 22-34 mm, the ultra wide's at 14-21 mm, the telephoto's above 45 mm.
PHONE_MAIN_35MM = (20.0, 40.0)
#: Words of a phone profile's lens and setting text naming one of the phone's cameras, in this order.
_PHONE_LENS_WORDS = (
    ("front", r"front|selfie|true ?depth"),
    ("ultra wide", r"ultra ?wide|\buw\b|\b0[.,][56] ?x?\b|\b1[0-7] ?mm"),
    ("telephoto", r"tele|\b[2-9](\.\d)? ?x\b|\b(4[5-9]|[5-9]\d|1\d\d) ?mm"),
    ("main", r"main|primary|wide|\b1(\.0)? ?x\b|standard|normal|default|\b2\d ?mm"),
)
_EIS_OFF = r"no[ -]?eis|eis[ -]?off|off[ -]?eis|stab(ilization)?[ -]?off|eis[ -]?n\b|non[ -]?eis"
_EIS_ON = r"\beis\b|eis-y|hs\b|hypersmooth|boost|hlevel|horizon|stab(ilization)?[ -]?on|rocksteady|steady"


@dataclass(frozen=True)
class LensProfile:
    """One calibration of the database (pixels at its calibration size ``width`` x ``height``)."""

    brand: str
    model: str
    lens: str
    setting: str
    width: int
    height: int
    fps: float | None
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float]
    rms: float | None
    images: int
    official: bool
    readout_ms: float | None
    stretch: float
    digital_lens: str
    compatible: tuple[tuple[int, int], ...]

    @property
    def name(self) -> str:
        """Human description: ``GoPro HERO6 Black, Wide, NO-EIS, 2704x1520 @ 29.97 fps``."""
        words = [f"{self.brand} {self.model}".strip()]
        words += [w for w in (self.lens, self.setting) if w]
        rate = f" @ {self.fps:g} fps" if self.fps else ""
        return ", ".join(words) + f", {self.width}x{self.height}{rate}"

    @property
    def eis(self) -> bool | None:
        """Whether the profile was calibrated with electronic stabilisation on (None: not said)."""
        return stabilization_state(f"{self.lens} {self.setting}")

    @property
    def lens_class(self) -> str:
        """The lens class of the profile's words (``"wide"``, ``"linear"``, ...; ``""``: none)."""
        return lens_class(f"{self.lens} {self.setting}", self.model)

    @property
    def phone_lens(self) -> str:
        """Which of a phone's cameras the profile's words name (:func:`phone_lens`; ``""``: none)."""
        return phone_lens(f"{self.lens} {self.setting}")

    @property
    def focal_35mm(self) -> float:
        """The profile's 35 mm-equivalent focal length (mm, on the diagonal of its picture)."""
        return self.fx * math.hypot(36.0, 24.0) / math.hypot(self.width, self.height)


@dataclass(frozen=True)
class LensMatch:
    """A profile scaled to a video of ``width`` x ``height`` pixels (display orientation).

    ``fx, fy, cx, cy`` in pixels of the video; ``distortion`` OpenCV fisheye ``k1..k4``;
    ``readout_ms`` the profile's frame readout time (ms, negative: bottom row first) or None;
    ``candidates`` how many profiles tied for the choice, ``spread`` their focal lengths' relative
    spread; ``reason`` in words.
    """

    profile: LensProfile
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float]
    readout_ms: float | None
    candidates: int
    spread: float
    reason: str

    def to_dict(self) -> dict:
        """JSON-ready description."""
        return {
            "profile": self.profile.name,
            "calibration_size": [self.profile.width, self.profile.height],
            "official": self.profile.official,
            "rms_px": self.profile.rms,
            "focal_px": round(0.5 * (self.fx + self.fy), 3),
            "distortion_fisheye_k": [round(k, 6) for k in self.distortion],
            "readout_ms": self.readout_ms,
            "candidates": self.candidates,
            "spread": round(self.spread, 4),
            "reason": self.reason,
        }


@dataclass(frozen=True)
class LensLookup:
    """The outcome of :func:`find_profile`: ``match`` (or None) and, in words, why."""

    match: LensMatch | None
    reason: str


def _norm(text: str) -> str:
    return re.sub(r"[^0-9a-z]+", "", str(text).lower())


def model_key(brand: str | None, model: str | None) -> str:
    """A camera model compared without case, punctuation, spaces or a leading brand name."""
    b, m = _norm(brand or ""), _norm(model or "")
    if b and m.startswith(b):
        m = m[len(b) :]
    return m


def brand_key(brand: str | None) -> tuple[str, str]:
    """A maker's name as (brand, sub-brand), normalised: ``"Samsung Electronics"`` →
    ``("samsung", "")``, ``"Redmi"`` → ``("xiaomi", "redmi")`` (:data:`BRAND_ALIASES`,
    :data:`SUB_BRANDS`)."""
    b = _norm(brand or "")
    b = BRAND_ALIASES.get(b, b)
    return (SUB_BRANDS[b], b) if b in SUB_BRANDS else (b, "")


def camera_key(brand: str | None, model: str | None) -> str:
    """Brand and model as one key (:func:`brand_key` then :func:`model_key`): the maker's brand,
    its sub-brand, then the model without case, punctuation, a repeated brand or a series word
    (``("Apple", "iPhone13Pro")`` = ``("apple", "iPhone 13 Pro")``, ``("samsung", "SM-G991B")`` =
    ``("Samsung", "Galaxy S21")``, ``("Xiaomi", "Redmi Note 10")`` = ``("Redmi", "Note 10")``)."""
    fam, sub = brand_key(brand)
    m = _norm(model or "")
    for prefix in dict.fromkeys((_norm(brand or ""), fam, sub)):
        if prefix and m.startswith(prefix) and len(m) > len(prefix):
            m = m[len(prefix) :]
    if fam == "samsung" and (code := re.fullmatch(r"sm([a-z]\d{3})[0-9a-z]*", m)) and code[1] in SAMSUNG_CODES:
        m = _norm(SAMSUNG_CODES[code[1]])
    for word in SERIES_WORDS.get(fam, ()):
        if m.startswith(word) and len(m) > len(word):
            m = m[len(word) :]
    return fam + sub + m


def phone_lens(text: str) -> str:
    """Which of a phone's cameras ``text`` (lens words) names: ``"front"``, ``"ultra wide"``,
    ``"telephoto"``, ``"main"``; ``""`` when it names none."""
    t = str(text).lower()
    return next((name for name, pattern in _PHONE_LENS_WORDS if re.search(pattern, t)), "")


def lens_class(text: str, model: str = "") -> str:
    """The lens class named by ``text`` (profile lens and setting words), ``""`` when none.

    ``"max"`` alone is GoPro MAX's Max SuperView on the MAX, and the Max Lens Mod on a HERO."""
    t = str(text).lower()
    for name, pattern in _LENS_WORDS:
        if re.search(pattern, t):
            if name in ("max", "max wide"):
                is_max = model_key("", model) in ("max", "gopromax")
                return ("max superview" if name == "max" else "wide") if is_max else "max lens mod"
            return name
    return ""


def stabilization_state(text: str) -> bool | None:
    """Whether words such as ``"HS EIS"`` (True) or ``"NO-EIS"`` (False) say electronic
    stabilisation was on; None when they say nothing."""
    t = str(text).lower()
    if re.search(_EIS_OFF, t):
        return False
    if re.search(_EIS_ON, t):
        return True
    return None


@functools.cache
def _index() -> tuple[list[str], dict, dict[str, list[int]], dict[str, list[int]]]:
    """The shipped index: its strings, its columns, and the rows of each :func:`model_key` and of
    each :func:`camera_key` (loaded once per process, about 0.3 s; profiles are built only for
    the model asked for)."""
    raw = resources.files("egovid.data").joinpath("lens_profiles.json.gz").read_bytes()
    doc = json.loads(gzip.decompress(raw))
    strings, cols = doc["strings"], doc["columns"]
    keys: dict[tuple[int, int], tuple[str, str]] = {}
    by_model: dict[str, list[int]] = {}
    by_camera: dict[str, list[int]] = {}
    for i, pair in enumerate(zip(cols["brand"], cols["model"], strict=True)):
        key = keys.get(pair)
        if key is None:
            b, m = strings[pair[0]], strings[pair[1]]
            key = keys[pair] = (model_key(b, m), camera_key(b, m))
        by_model.setdefault(key[0], []).append(i)
        by_camera.setdefault(key[1], []).append(i)
    return strings, cols, by_model, by_camera


def _profile(i: int) -> LensProfile:
    strings, cols = _index()[:2]

    def s(name: str) -> str:
        return strings[cols[name][i]]

    return LensProfile(
        brand=s("brand"),
        model=s("model"),
        lens=s("lens"),
        setting=s("setting"),
        width=int(cols["w"][i]),
        height=int(cols["h"][i]),
        fps=cols["fps"][i],
        fx=float(cols["fx"][i]),
        fy=float(cols["fy"][i]),
        cx=float(cols["cx"][i]),
        cy=float(cols["cy"][i]),
        distortion=tuple(float(cols[k][i] or 0.0) for k in ("k1", "k2", "k3", "k4")),
        rms=cols["rms"][i],
        images=int(cols["images"][i]),
        official=bool(cols["official"][i]),
        readout_ms=cols["readout_ms"][i],
        stretch=float(cols["stretch"][i] or 1.0),
        digital_lens=s("digital_lens"),
        compatible=tuple(tuple(c) for c in cols["compatible"][i]),
    )


def profiles_of(brand: str | None, model: str | None) -> tuple[LensProfile, ...]:
    """The profiles of one camera: of this brand and model (:func:`camera_key`) when ``brand``
    is given, else of every brand's model of this name (:func:`model_key`)."""
    if _norm(brand or ""):
        rows = _index()[3].get(camera_key(brand, model), [])
    else:
        rows = _index()[2].get(model_key("", model), [])
    return tuple(_profile(i) for i in rows)


def load_profiles() -> tuple[LensProfile, ...]:
    """All profiles of the shipped index."""
    return tuple(_profile(i) for i in range(len(_index()[1]["w"])))


def _lens_words(text: str) -> set[str]:
    return {w for w in re.split(r"[^0-9a-z.]+", str(text).lower()) if w and w not in ("f", "mm", "lens")}


def _usable(group: list[LensProfile], w: int, h: int) -> list[LensProfile]:
    """Profiles of a landscape ``w`` x ``h`` picture's aspect ratio, without a digital lens or a stretch."""
    aspect = w / h
    return [
        p
        for p in group
        if not p.digital_lens
        and abs(p.stretch - 1.0) < 1e-6
        and abs((p.width / p.height) / aspect - 1) <= MAX_ASPECT_ERROR
    ]


def _by_lens(
    usable: list[LensProfile], camera: str, lens: str | None, w: int, focal_px: float | None
) -> tuple[list[LensProfile], str] | LensLookup:
    """The profiles of the lens the file names (a GoPro lens-mode code or a lens name), or, when
    it names none, of the one lens the measured focal length fits; with a note saying which.
    A :class:`LensLookup` with the reason when no lens can be told."""
    want = LENS_CLASSES.get(lens.strip().upper()) if lens and len(lens.strip()) == 1 else None
    if lens and want is None and len(lens.strip()) > 1:
        words = _lens_words(lens)
        chosen = [p for p in usable if (pw := _lens_words(p.lens)) and (pw <= words or words <= pw)]
        return chosen, f"lens {lens}"
    if want is not None:
        if want in ("superview", "hyperview"):
            return LensLookup(None, f"{camera}'s {want} lens stretches the picture non-linearly (no fisheye profile)")
        return [p for p in usable if p.lens_class == want], f"{want} lens"
    chosen = [p for p in usable if p.lens_class not in ("anamorphic", "max lens mod")]
    named = sorted({p.lens_class for p in chosen} - {""})
    note = "no lens mode in the file"
    if len(named) > 1 and focal_px:
        near = sorted(
            {p.lens_class for p in chosen if p.lens_class and abs(p.fx * w / p.width / focal_px - 1) <= MAX_SPREAD}
        )
        if len(near) == 1:
            chosen = [p for p in chosen if p.lens_class == near[0]]
            named = near
            note = f"{near[0]} lens, the one the measured {focal_px:.0f} px focal length fits"
    if len(named) > 1:
        return LensLookup(None, f"the file does not say which of {camera}'s lenses ({', '.join(named)}) was used")
    return chosen, note


def _by_phone_lens(usable: list[LensProfile], camera: str, lens: str | None) -> tuple[list[LensProfile], str]:
    """The profiles of the phone camera the file's lens words name, else of the main (wide) one:
    those whose words name it, else those that name none; each only where its focal length is
    that camera's (the main camera: :data:`PHONE_MAIN_35MM`); with a note saying which."""
    said = phone_lens(lens) if lens else ""
    want = said or "main"
    note = f"{want} camera, as the file says ({lens})" if said else (
        "main (wide) camera, assumed: the file does not say which of the phone's cameras"
    )  # fmt: skip
    lo, hi = PHONE_MAIN_35MM
    if want == "main":
        fits = [p for p in usable if lo <= p.focal_35mm <= hi]
    elif want == "ultra wide":
        fits = [p for p in usable if p.focal_35mm < lo]
    elif want == "telephoto":
        fits = [p for p in usable if p.focal_35mm > hi]
    else:
        fits = usable
    chosen = [p for p in fits if p.phone_lens == want]
    if not chosen and want in ("main", "ultra wide", "telephoto"):
        chosen = [p for p in fits if not p.phone_lens]
        if chosen:
            note += f"; {camera}'s profiles that name no camera, at a {want} camera's focal length"
    return chosen, note


def _agreeing(
    chosen: list[LensProfile], w: int, h: int, stabilized: bool | None, fps: float | None, focal_px: float | None
) -> tuple[list[LensProfile], float]:
    """The best-ranked profiles (same size or compatible first, then matching stabilisation, the
    nearest frame rate, official) that the measured focal length fits, with the relative spread
    of their focal lengths; scattered community profiles keep their middle half."""

    def rank(p: LensProfile) -> tuple:
        fps_err = abs(math.log(p.fps / fps)) if fps and p.fps and p.fps > 0 else 9.0
        return (
            0 if _same_size(p, w, h) else 1,
            0 if stabilized is None or p.eis is stabilized else 1,
            round(fps_err, 2),
            0 if p.official else 1,
        )

    best = min(rank(p) for p in chosen)
    tied = [p for p in chosen if rank(p) == best]
    if focal_px:  # a measured focal length also tells stabilised (cropped) from plain calibrations
        tied = [p for p in tied if abs(p.fx * w / p.width / focal_px - 1) <= MAX_SPREAD] or tied
    rel = [p.fx / p.width for p in tied]
    spread = max(rel) / min(rel) - 1.0
    if spread > MAX_SPREAD and len(tied) > 2:
        order = sorted(range(len(tied)), key=lambda k: rel[k])
        tied = [tied[k] for k in order[len(order) // 4 : len(order) - len(order) // 4]]
        rel = [p.fx / p.width for p in tied]
        spread = max(rel) / min(rel) - 1.0
    return tied, spread


def _same_size(p: LensProfile, w: int, h: int) -> bool:
    return (p.width, p.height) == (w, h) or (w, h) in p.compatible


def _match(
    tied: list[LensProfile],
    spread: float,
    width: int,
    height: int,
    fps: float | None,
    lens_note: str,
    rotation: int,
) -> LensLookup:
    """The medoid of the agreeing profiles, scaled to the sensor's (landscape) picture and turned
    as the decoder turns the frames: by the display ``rotation`` flag (degrees counter-clockwise);
    a picture coded in portrait is taken as turned 270° more (as a phone held upright records)."""
    turn = rotation % 360
    w, h = (height, width) if turn % 180 == 90 else (width, height)  # the coded picture
    how_turned = f"turned {turn}° by the file's rotation flag" if turn else ""
    if h > w:
        w, h, turn = h, w, (turn + 270) % 360
        how_turned = "coded in portrait: taken as the sensor's picture turned 270°"
    rel = [p.fx / p.width for p in tied]
    medoid = min(range(len(tied)), key=lambda k: (sum(abs(rel[k] - r) for r in rel), tied[k].rms or 9.0))
    p = tied[medoid]
    s = w / p.width
    sy = h / p.height
    coded = Intrinsics(w, h, p.fx * s, p.fy * sy, (p.cx + 0.5) * s - 0.5, (p.cy + 0.5) * sy - 0.5)
    shown = coded.rotated(turn)
    fx, fy, cx, cy = shown.fx, shown.fy, shown.cx, shown.cy
    exact = _same_size(p, w, h)
    readout = p.readout_ms if exact and p.readout_ms and (not fps or not p.fps or abs(p.fps / fps - 1) < 0.02) else None
    how = "at this size" if exact else f"scaled {s:.4g}x"
    how += f", {how_turned}" if how_turned else ""
    reason = f"{p.name} ({how}; {lens_note}; {len(tied)} profile(s) agree within {100 * spread:.1f} %)"
    return LensLookup(
        LensMatch(p, width, height, fx, fy, cx, cy, p.distortion, readout, len(tied), spread, reason), reason
    )


def find_profile(
    brand: str | None,
    model: str | None,
    width: int,
    height: int,
    *,
    lens: str | None = None,
    stabilized: bool | None = None,
    fps: float | None = None,
    focal_px: float | None = None,
    phone: bool = False,
    rotation: int = 0,
) -> LensLookup:
    """The profile of a camera for a ``width`` x ``height`` video (pixels, display orientation)
    recorded at ``fps``; see the module docstring for the rules.

    ``lens``: a GoPro lens-mode code (``"W"``, ``"M"``...) or a lens name; ``stabilized``: whether
    the camera stabilised the picture electronically (None: unknown, then only profiles that
    agree among themselves are used); ``focal_px``: a focal length measured on the video (the
    gyro fit, pixels), which picks the lens when the file names none: the one lens whose profile
    is within :data:`MAX_SPREAD` of it; ``phone``: the camera is a phone (make and model from its
    container's own keys), whose several cameras are told apart by ``lens`` words, else its main
    camera is taken; ``rotation``: the container's display rotation flag (degrees
    counter-clockwise, as the decoder turns the frames; ``width`` x ``height`` are after it; a
    picture coded in portrait is taken as the sensor's turned 270°).
    Never raises for unknown cameras: the reason says why nothing matched.
    """
    key = model_key(brand, model)
    camera = " ".join(x for x in (brand, model) if x) or "the camera"
    if not key:
        return LensLookup(None, "the file names no camera model")
    group = profiles_of(brand, model)
    if not group:
        same_name = {p.brand for p in profiles_of("", model)} if brand else set()
        other = f" (the database's {model} is {', '.join(sorted(same_name))}'s)" if same_name else ""
        return LensLookup(None, f"no lens profile of {camera}{other}")
    w, h = (height, width) if height > width else (width, height)  # profiles are landscape
    usable = _usable(group, w, h)
    if not usable:
        return LensLookup(None, f"no profile of {camera} at the aspect ratio {w}:{h} without a digital lens")
    by_lens = _by_phone_lens(usable, camera, lens) if phone else _by_lens(usable, camera, lens, w, focal_px)
    if isinstance(by_lens, LensLookup):
        return by_lens
    chosen, lens_note = by_lens
    if not chosen:
        return LensLookup(None, f"no profile of {camera} with its {lens_note}")
    if stabilized is not None:
        chosen = [p for p in chosen if p.eis is stabilized] or [p for p in chosen if p.eis is None]
        if not chosen:
            state = "on" if stabilized else "off"
            return LensLookup(None, f"no profile of {camera} ({lens_note}) with electronic stabilisation {state}")
    tied, spread = _agreeing(chosen, w, h, stabilized, fps, focal_px)
    if spread > MAX_SPREAD:
        return LensLookup(
            None,
            f"{len(tied)} profiles of {camera} ({lens_note}) disagree on the focal length by {100 * spread:.0f} %",
        )
    return _match(tied, spread, width, height, fps, lens_note, rotation)
