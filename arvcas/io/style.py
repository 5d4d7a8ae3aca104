"""The house style of arvcas's figures, in one place: sizes for a journal's columns, fonts, line widths,
a colour-blind-safe palette, how dense noisy series are drawn, and the formats a figure is written in.

Every figure function of arvcas draws inside :func:`styled` (a decorator: matplotlib's ``rc_context``
around the function, so nothing global changes) into a Figure from :func:`figure`, and is written by
:func:`write_figure` (atomically, through :func:`arvcas.util.files.atomic_write`) in one of :data:`FORMATS`.

* **Sizes.** A single journal column is 3.5 in (88-90 mm: Elsevier 90 mm, IEEE and MDPI 88.9 mm), a
  full page width 7.16 in (182 mm). Text is set at 8 pt (tick labels and legends 7 pt), the size
  journals ask for at print size; figures are made at their print size, so no scaling changes it.
* **Lines.** 0.8 pt data lines, 0.5 pt axes and ticks, 0.4 pt grid.
* **Colours.** The Okabe-Ito palette (Okabe and Ito 2008, *Color Universal Design*; the palette
  Wong 2011, *Nature Methods* 8, 441, recommends), distinguishable under the common colour-vision
  deficiencies. It is the colour cycle (``C0``..``C7``), and matplotlib's ``tab:`` names, which the
  controllers use as their colours (:attr:`arvcas.controllers.Controller.color`), map through
  :func:`color` to the palette's nearest hue: a controller keeps its hue family in every figure.
* **Dense noisy series** (:func:`trace`): a series with many more samples than its panel has points
  of width, and that reverses direction at most samples (chattering thrust, a zigzagging gain) is
  drawn as the band between its minimum and maximum in each bin of about one point of width, with
  the bin's mean as a line: at column width a raw line of 1000 such samples is a solid block that
  hides both the level and the amplitude. Smooth series, and any series with few samples, are drawn
  sample by sample.
* **Formats** (:data:`FORMATS`): PNG at :data:`PNG_DPI`, PDF with TrueType fonts (type 42, which
  journals accept and editors can change; matplotlib's default type 3 is refused by some), SVG with
  text kept as text. Outputs are byte-reproducible: no creation date is written and SVG ids are
  seeded.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from arvcas.util import files

__all__ = ["COLUMN_WIDTH", "PAGE_WIDTH", "PALETTE", "FORMATS", "PNG_DPI", "RC", "styled", "figure", "color",
           "trace", "log_labels", "figure_format", "save", "write_figure"]

COLUMN_WIDTH = 3.5  # in: one journal column (88-90 mm)
PAGE_WIDTH = 7.16  # in: the full text width of a two-column page (182 mm)

# Okabe-Ito: black, orange, sky blue, bluish green, yellow, blue, vermillion, reddish purple
PALETTE = {
    "blue": "#0072B2", "vermillion": "#D55E00", "bluish green": "#009E73", "reddish purple": "#CC79A7",
    "orange": "#E69F00", "sky blue": "#56B4E9", "yellow": "#F0E442", "black": "#000000",
}
_CYCLE = ("blue", "vermillion", "bluish green", "reddish purple", "orange", "sky blue", "black", "yellow")
# matplotlib's tab: colours (the names controllers give) -> the palette's nearest hue
_TAB = {"tab:blue": "blue", "tab:orange": "orange", "tab:green": "bluish green", "tab:red": "vermillion",
        "tab:purple": "reddish purple", "tab:cyan": "sky blue", "tab:olive": "yellow", "tab:gray": "black",
        "tab:grey": "black", "tab:brown": "vermillion", "tab:pink": "reddish purple"}

FORMATS = ("png", "pdf", "svg")
PNG_DPI = 200

RC = {
    "font.size": 8, "axes.titlesize": 8, "axes.labelsize": 8, "xtick.labelsize": 7, "ytick.labelsize": 7,
    "legend.fontsize": 7, "figure.titlesize": 9, "legend.title_fontsize": 7,
    "lines.linewidth": 0.8, "lines.markersize": 3.5, "axes.linewidth": 0.5, "grid.linewidth": 0.4,
    "xtick.major.width": 0.5, "ytick.major.width": 0.5, "xtick.minor.width": 0.4, "ytick.minor.width": 0.4,
    "xtick.major.size": 2.5, "ytick.major.size": 2.5, "xtick.minor.size": 1.5, "ytick.minor.size": 1.5,
    "patch.linewidth": 0.5, "legend.frameon": False, "legend.handlelength": 1.8, "axes.titlepad": 3.0,
    "figure.constrained_layout.h_pad": 0.02, "figure.constrained_layout.w_pad": 0.02,
    "pdf.fonttype": 42, "ps.fonttype": 42, "svg.fonttype": "none", "svg.hashsalt": "arvcas",
    "savefig.dpi": PNG_DPI, "mathtext.default": "it",
}


def _rc() -> dict:
    from cycler import cycler

    return {**RC, "axes.prop_cycle": cycler(color=[PALETTE[c] for c in _CYCLE])}


def styled(fn):
    """Run a figure function under the house style (matplotlib's ``rc_context``: nothing global changes)."""
    @functools.wraps(fn)
    def wrapper(*args, **kw):
        import matplotlib

        with matplotlib.rc_context(_rc()):
            return fn(*args, **kw)

    return wrapper


def figure(width: str | float = "column", height: float | None = None):
    """An empty :class:`matplotlib.figure.Figure` (no pyplot) of ``width`` ``"column"`` (3.5 in),
    ``"page"`` (7.16 in) or inches, ``height`` in inches (default 0.75 of the width), constrained layout."""
    from matplotlib.figure import Figure

    w = {"column": COLUMN_WIDTH, "page": PAGE_WIDTH}.get(width, width) if isinstance(width, str) else float(width)
    if isinstance(w, str):
        raise ValueError(f"figure width {width!r}: expected 'column', 'page' or inches")
    return Figure(figsize=(w, 0.75 * w if height is None else height), layout="constrained")


def color(c, i: int = 0) -> str:
    """A colour in the house palette: a ``tab:`` name or a cycle name ``"C3"`` mapped to the palette, a
    palette name (``"vermillion"``), anything else (hex, grey levels, user colours) as given; ``""`` or
    None: cycle colour ``i``."""
    if not c:
        return PALETTE[_CYCLE[i % len(_CYCLE)]]
    if isinstance(c, str):
        if c in _TAB:
            return PALETTE[_TAB[c]]
        if c in PALETTE:
            return PALETTE[c]
        if len(c) == 2 and c[0] == "C" and c[1].isdigit():
            return PALETTE[_CYCLE[int(c[1]) % len(_CYCLE)]]
    return c


def log_labels(ax) -> None:
    """Plain numbers on log axes (0.3, 0.5, 1, 2) instead of 3 x 10^-1: the minor ticks at mantissas 2, 3
    and 5 are labelled only where a decade would otherwise have fewer than two labels."""
    from matplotlib.ticker import FuncFormatter

    def major(v, _pos):
        return f"{v:g}"

    def minor(v, _pos):
        m = v / 10 ** np.floor(np.log10(v)) if v > 0 else 0
        return f"{v:g}" if any(abs(m - k) < 1e-6 for k in (2, 3, 5)) else ""

    for axis in (ax.xaxis, ax.yaxis):
        if axis.get_scale() == "log":
            lo, hi = sorted(axis.get_view_interval())
            axis.set_major_formatter(FuncFormatter(major))
            few = lo > 0 and np.log10(hi / lo) < 2.0
            axis.set_minor_formatter(FuncFormatter(minor) if few else FuncFormatter(lambda v, _p: ""))


# ---- dense noisy series --------------------------------------------------------------------------------------

REVERSALS = 0.3  # share of samples where the series turns (sign change of its increments) to count as noisy
SAMPLES_PER_POINT = 3.0  # more samples than this per point of panel width: dense


def _width_points(ax) -> float:
    """The panel's width in points (from its position in the figure; constrained layout adjusts it
    a little later)."""
    fig = ax.figure
    return max(1.0, ax.get_position().width * fig.get_figwidth() * 72.0)


def is_dense_noisy(y: np.ndarray, width_points: float) -> bool:
    """True if ``y`` has more than :data:`SAMPLES_PER_POINT` samples per point of ``width_points`` and
    turns at more than :data:`REVERSALS` of its samples."""
    y = np.asarray(y, dtype=float)
    y = y[np.isfinite(y)]
    if y.size <= SAMPLES_PER_POINT * width_points or y.size < 3:
        return False
    d = np.diff(y)
    turns = np.count_nonzero(d[1:] * d[:-1] < 0)
    return turns > REVERSALS * (y.size - 2)


def envelope(t: np.ndarray, y: np.ndarray, bins: int):
    """Per-bin ``(t_mid, lo, hi, mean)`` of ``y`` over ``bins`` equal runs of samples (NaNs ignored)."""
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    edges = np.linspace(0, y.size, bins + 1).astype(int)
    keep = np.diff(edges) > 0
    lo_i, hi_i = edges[:-1][keep], edges[1:][keep]
    with np.errstate(all="ignore"):
        lo = np.array([np.nanmin(y[a:b]) if np.isfinite(y[a:b]).any() else np.nan for a, b in zip(lo_i, hi_i)])
        hi = np.array([np.nanmax(y[a:b]) if np.isfinite(y[a:b]).any() else np.nan for a, b in zip(lo_i, hi_i)])
        mean = np.array([np.nanmean(y[a:b]) if np.isfinite(y[a:b]).any() else np.nan for a, b in zip(lo_i, hi_i)])
    tm = 0.5 * (t[lo_i] + t[hi_i - 1])
    return tm, lo, hi, mean


def trace(ax, t, y, color=None, lw: float | None = None, label: str | None = None, zorder: float | None = None,
          **kw):
    """Draw one time series: a line, or for a dense noisy one (module docstring) its min-max band per
    bin of about one point with the bin means as the line. Returns the line (whose label is ``label``)."""
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    width = _width_points(ax)
    line_kw = {k: v for k, v in (("color", color), ("lw", lw), ("label", label), ("zorder", zorder)) if v is not None}
    if not is_dense_noisy(y, width):
        return ax.plot(t, y, **line_kw, **kw)[0]
    tm, lo, hi, mean = envelope(t, y, int(width))
    (line,) = ax.plot(tm, mean, **line_kw, **kw)
    ax.fill_between(tm, lo, hi, color=line.get_color(), alpha=0.3, lw=0, zorder=line.get_zorder() - 0.01)
    return line


# ---- formats -------------------------------------------------------------------------------------------------


def figure_format(path, fmt: str | None = None, what: str | None = None) -> str:
    """The format to write ``path`` in: ``fmt`` if given (it must agree with a figure suffix of ``path``),
    else the suffix; ValueError (one line) for a format arvcas does not write."""
    p = Path(path)
    suffix = p.suffix.lower().lstrip(".")
    label = what or str(p)
    allowed = ", ".join(FORMATS)
    if fmt is not None:
        fmt = fmt.lower()
        if fmt not in FORMATS:
            raise ValueError(f"--format {fmt}: arvcas writes figures as {allowed}")
        if suffix and suffix != fmt and suffix in FORMATS + ("jpg", "jpeg", "eps", "ps", "tif", "tiff", "webp"):
            raise ValueError(f"{label}: the name ends in .{suffix} but --format is {fmt}; make them agree")
        return fmt
    if suffix in FORMATS:
        return suffix
    if not suffix:
        raise ValueError(f"{label}: no suffix to take the figure format from; end the name in .png, .pdf or "
                         f".svg or give --format")
    raise ValueError(f"{label}: cannot write .{suffix} figures (arvcas writes {allowed}; end the name in one of "
                     f"them or give --format)")


def save(fig, path, fmt: str) -> None:
    """Write ``fig`` to ``path`` in ``fmt`` (one of :data:`FORMATS`), reproducibly (module docstring)."""
    import matplotlib

    from arvcas._version import __version__

    if fmt not in FORMATS:
        raise ValueError(f"figure format {fmt!r}: arvcas writes {', '.join(FORMATS)}")
    meta = {"png": {"Software": f"arvcas {__version__}"},
            "pdf": {"Creator": f"arvcas {__version__}", "CreationDate": None},
            "svg": {"Creator": f"arvcas {__version__}", "Date": None}}[fmt]
    with matplotlib.rc_context(_rc()):
        fig.savefig(path, format=fmt, dpi=PNG_DPI if fmt == "png" else None, metadata=meta)


def write_figure(path, fig, fmt: str | None = None, error: type[ValueError] = files.FileError) -> Path:
    """A matplotlib figure, written atomically (:func:`arvcas.util.files.atomic_write`) in ``fmt`` (``png``,
    ``pdf`` or ``svg``; default: from the name's suffix) by :func:`save`; its kind is ``fmt``."""
    try:
        fmt = figure_format(path, fmt)
    except ValueError as e:
        raise error(str(e)) from None
    return files.atomic_write(path, lambda p: save(fig, p, fmt), error, fmt)
