"""Image files: linear radiance in and out (layer 1).

One pair of functions, :func:`write_image` and :func:`read_image`, chooses the
format from the file's suffix:

========  =====================================  ===========================
suffix    stores                                 through
========  =====================================  ===========================
``.npy``  linear float32 ``(H, W, 3)``           :func:`numpy.save`
``.exr``  linear float32 RGB (OpenEXR)           the ``OpenEXR`` package
``.hdr``  linear RGBE, run-length encoded        this module (Ward's format)
``.png``  8-bit sRGB, tonemapped by clipping     Pillow (via imageio)
========  =====================================  ===========================

Every image is an ``(H, W, 3)`` array with **row 0 at the top**, as in
``docs/conventions.md``. :func:`read_image` returns float64; a file that cannot
be decoded (truncated, corrupt, or another format under the suffix) is a
``ValueError`` naming the file, never a silently black image; a missing file is
the usual :class:`FileNotFoundError`, a directory an :class:`IsADirectoryError`.

Radiance ``.hdr`` is read and written here because no installed library does
it without a binary download: imageio's RGBE support lives in its FreeImage
plugin (fetched at run time), and with that absent ``imageio.v3.imwrite`` falls
back to writing a *TIFF* under the ``.hdr`` name. The codec below follows Greg
Ward's description of the format [1]_ [2]_.

References
----------
.. [1] G. Ward, "Real Pixels", in *Graphics Gems II*, J. Arvo (ed.), Academic
   Press, 1991, pp. 80-83.
.. [2] G. Ward, "The RADIANCE Picture File Format" (Radiance reference
   manual, ``refer/filefmts.pdf``), Lawrence Berkeley National Laboratory.
.. [3] IEC 61966-2-1:1999, *Multimedia systems and equipment - Colour
   measurement and management - Part 2-1: Default RGB colour space - sRGB*.
"""
from __future__ import annotations

import os
import pathlib
import re

import numpy as np

from ._validation import as_array, check_positive

__all__ = [
    "SUFFIXES",
    "write_image",
    "read_image",
    "to_srgb8",
    "linear_to_srgb",
    "srgb_to_linear",
    "rgbe_encode",
    "rgbe_decode",
]

#: Suffixes understood by :func:`write_image` and :func:`read_image`.
SUFFIXES = (".npy", ".exr", ".hdr", ".png")


# --------------------------------------------------------------------------
# sRGB transfer curve (IEC 61966-2-1)
# --------------------------------------------------------------------------

def linear_to_srgb(values) -> np.ndarray:
    """Encode linear values in [0, 1] with the exact sRGB transfer curve.

    Notes
    -----
    The piecewise curve of IEC 61966-2-1 [3]_::

        V = 12.92 L                      for L <= 0.0031308
        V = 1.055 L^(1/2.4) - 0.055      otherwise

    Input is clipped to [0, 1] first (sRGB has no values outside it).
    """
    x = np.clip(as_array(values, "values"), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def srgb_to_linear(values) -> np.ndarray:
    """Decode sRGB values to linear, the inverse of :func:`linear_to_srgb`.

    ``uint8`` input is read as code values ``0..255`` (divided by 255); float
    input must lie in [0, 1].

    Notes
    -----
    IEC 61966-2-1 [3]_: ``L = V / 12.92`` for ``V <= 0.04045``, else
    ``L = ((V + 0.055) / 1.055)^2.4``.
    """
    try:
        arr = np.asarray(values)
    except ValueError as exc:  # ragged nested lists
        raise TypeError(f"values must be array-like of real numbers; got {type(values).__name__}") from exc
    if arr.dtype == np.uint8:
        v = arr.astype(np.float64) / 255.0
    else:
        v = as_array(values, "values")
        if v.size and not (np.all(v >= 0.0) and np.all(v <= 1.0)):
            raise ValueError(f"values must lie in [0, 1] (or be uint8); got [{v.min()}, {v.max()}]")
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4))


def to_srgb8(image, *, exposure: float = 1.0) -> np.ndarray:
    """Tonemap linear radiance to 8-bit sRGB for display.

    Parameters
    ----------
    image : array_like, shape (H, W, 3)
        Linear radiance; finite.
    exposure : float, optional
        A linear multiplier applied before clipping: the displayed value is
        ``clip(exposure * L, 0, 1)``. ``exposure = 2 ** stops`` brightens by
        ``stops`` photographic stops. Default 1: radiance 1 is white.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        ``round(255 * srgb(clip(exposure * L, 0, 1)))``.

    Notes
    -----
    The tonemap is a plain clip (no curve), so that a pixel's value can be
    read back exactly where it is below white: :func:`srgb_to_linear` of the
    result recovers ``exposure * L`` to within half an 8-bit code step.
    """
    img = _check_image(image, "image")
    exposure = check_positive(exposure, "exposure")
    codes = np.rint(255.0 * linear_to_srgb(exposure * img))
    return codes.astype(np.uint8)


# --------------------------------------------------------------------------
# Radiance RGBE
# --------------------------------------------------------------------------

def rgbe_encode(image) -> np.ndarray:
    """Pack linear RGB into Ward's shared-exponent RGBE bytes.

    Parameters
    ----------
    image : array_like, shape (..., 3)
        Finite, non-negative linear values.

    Returns
    -------
    ndarray of uint8, shape (..., 4)

    Notes
    -----
    With ``m = max(R, G, B) = f 2^e``, ``f`` in [0.5, 1) (``frexp``), each
    channel is stored as ``floor(c 256 / 2^e)`` and the exponent as
    ``e + 128`` [1]_. A pixel whose maximum is below ``2^-128`` (or zero)
    becomes ``(0, 0, 0, 0)``. Decoding with :func:`rgbe_decode` puts each
    value at its quantisation cell's centre, so every channel comes back
    within ``2^-8 m`` of its value: a relative error of at most 0.4 % for the
    brightest channel.
    """
    rgb = as_array(image, "image", last=3, nonnegative=True)
    m = np.maximum(np.maximum(rgb[..., 0], rgb[..., 1]), rgb[..., 2])
    _, e = np.frexp(m)
    if np.any(e > 127):
        raise ValueError(f"image values must be < 2^127 to fit RGBE; got a maximum of {m.max()}")
    zero = (e + 128 <= 0) | (m == 0.0)  # below 2^-128 (Radiance: 1e-32) or black
    # 256 / 2^e built from its bit pattern: exact, and much faster than ldexp
    biased = np.clip(1023 + 8 - e.astype(np.int64), 1, 2046)
    scale = (biased << 52).view(np.float64)
    q = rgb * scale[..., None]
    np.minimum(q, 255.0, out=q)  # c <= m < 2^e, so only rounding can reach 256
    out = np.empty(rgb.shape[:-1] + (4,), dtype=np.uint8)
    out[..., :3] = q.astype(np.uint8)  # truncation is floor for q >= 0
    out[..., 3] = np.where(zero, 0, e + 128).astype(np.uint8)
    out[zero] = 0
    return out


def rgbe_decode(rgbe) -> np.ndarray:
    """Unpack RGBE bytes to linear float64 RGB, the inverse of :func:`rgbe_encode`.

    Notes
    -----
    ``c = (byte + 0.5) 2^(E - 136)`` for ``E > 0``, and 0 for ``E = 0``, as in
    Radiance's ``colr_color`` [2]_.
    """
    b = np.asarray(rgbe)
    if b.dtype != np.uint8 or b.ndim == 0 or b.shape[-1] != 4:
        raise ValueError(f"rgbe must be a uint8 array of shape (..., 4); got {b.dtype} {b.shape}")
    e = b[..., 3].astype(np.int64)
    f = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return (b[..., :3].astype(np.float64) + 0.5) * f[..., None]


_RESOLUTION = re.compile(rb"^([-+])([YX]) (\d+) ([-+])([YX]) (\d+)$")


def _write_hdr(path: pathlib.Path, image: np.ndarray) -> None:
    if np.any(image < 0):
        raise ValueError(f"{path}: Radiance RGBE cannot store negative values; "
                         f"got a minimum of {image.min()}")
    h, w, _ = image.shape
    rgbe = rgbe_encode(image)
    header = (b"#?RADIANCE\n# written by mcvar.images\nFORMAT=32-bit_rle_rgbe\n\n"
              + f"-Y {h} +X {w}\n".encode("ascii"))
    if 8 <= w <= 0x7FFF:
        body = _rle_encode(rgbe)
    else:  # the run-length scheme only covers widths 8..32767: store flat
        body = rgbe.tobytes()
    with open(path, "wb") as fh:
        fh.write(header)
        fh.write(body)


def _rle_encode(rgbe: np.ndarray) -> bytes:
    """New-style (1991) run-length encoding: each scanline is ``2 2 W_hi W_lo``
    followed by its four channels one after another, each as packets: a byte
    ``128 + n`` then one value repeated ``n <= 127`` times, or a byte
    ``n <= 128`` then ``n`` literal values. Runs of 4 or more equal bytes are
    packed as runs (Radiance's ``MINRUN``), everything else as literals.
    Vectorised over the whole image."""
    h, w, _ = rgbe.shape
    seq = np.ascontiguousarray(rgbe.transpose(0, 2, 1)).reshape(-1)  # rows, channels, pixels
    # maximal runs of equal bytes, never crossing a (row, channel) sequence
    brk = np.zeros(seq.size, dtype=bool)
    brk[0] = True
    brk[1:] = seq[1:] != seq[:-1]
    brk[::w] = True
    starts = np.flatnonzero(brk)
    lengths = np.diff(np.append(starts, seq.size))
    is_run = lengths >= 4
    # group consecutive short runs of one sequence into literal segments
    seq_id = starts // w
    new_seg = np.ones(starts.size, dtype=bool)
    new_seg[1:] = is_run[1:] | is_run[:-1] | (seq_id[1:] != seq_id[:-1])
    seg_first = np.flatnonzero(new_seg)
    seg_start = starts[seg_first]
    seg_len = np.add.reduceat(lengths, seg_first)
    seg_run = is_run[seg_first]
    # split segments into packets: runs of <= 127, literals of <= 128
    cap = np.where(seg_run, 127, 128)
    n_pk = -(-seg_len // cap)
    pk_seg = np.repeat(np.arange(seg_len.size), n_pk)
    pk_k = np.arange(pk_seg.size) - np.repeat(np.cumsum(n_pk) - n_pk, n_pk)
    pk_start = seg_start[pk_seg] + pk_k * cap[pk_seg]
    pk_len = np.minimum(cap[pk_seg], seg_start[pk_seg] + seg_len[pk_seg] - pk_start)
    pk_run = seg_run[pk_seg]
    pk_bytes = 1 + np.where(pk_run, 1, pk_len)
    # scanline headers go before the first packet of each row's channel 0
    pk_row_first = np.zeros(pk_seg.size, dtype=bool)
    first_of_seq = np.flatnonzero(pk_start % w == 0)
    pk_row_first[first_of_seq[(pk_start[first_of_seq] // w) % 4 == 0]] = True
    size = pk_bytes + 4 * pk_row_first
    out = np.empty(int(size.sum()), dtype=np.uint8)
    off = np.cumsum(size) - size
    hdr_off = off[pk_row_first]
    out[hdr_off] = 2
    out[hdr_off + 1] = 2
    out[hdr_off + 2] = w >> 8
    out[hdr_off + 3] = w & 0xFF
    poff = off + 4 * pk_row_first
    out[poff] = np.where(pk_run, 128 + pk_len, pk_len).astype(np.uint8)
    out[poff[pk_run] + 1] = seq[pk_start[pk_run]]
    lit = ~pk_run
    lit_len = pk_len[lit]
    total = int(lit_len.sum())
    k = np.arange(total) - np.repeat(np.cumsum(lit_len) - lit_len, lit_len)
    out[np.repeat(poff[lit] + 1, lit_len) + k] = seq[np.repeat(pk_start[lit], lit_len) + k]
    return out.tobytes()


def _read_hdr(path: pathlib.Path) -> np.ndarray:
    data = path.read_bytes()
    if not data.startswith(b"#?"):
        raise ValueError(f"{path}: not a Radiance RGBE file (no '#?' signature)")
    pos = 0
    fmt = None
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise ValueError(f"{path}: truncated Radiance header (no blank line before the resolution)")
        line = data[pos:end].strip()
        pos = end + 1
        if not line:
            break
        if line.startswith(b"FORMAT="):
            fmt = line[7:]
    if fmt not in (None, b"32-bit_rle_rgbe"):
        raise ValueError(f"{path}: unsupported Radiance FORMAT {fmt.decode(errors='replace')!r} "
                         "(only 32-bit_rle_rgbe; XYZE is not read)")
    end = data.find(b"\n", pos)
    match = _RESOLUTION.match(data[pos:end].strip()) if end >= 0 else None
    if match is None or match.group(2) == match.group(5):
        raise ValueError(f"{path}: bad Radiance resolution line {data[pos:max(end, pos)][:40]!r}")
    pos = end + 1
    s1, a1, n1, s2, a2, n2 = match.groups()
    n_major, n_minor = int(n1), int(n2)
    if n_major < 1 or n_minor < 1:
        raise ValueError(f"{path}: empty image ({n_major} x {n_minor})")
    rgbe = _decode_scanlines(data, pos, n_major, n_minor, path)
    img = rgbe_decode(rgbe)  # (n_major, n_minor, 3), in file order
    # orient to row 0 = top (-Y), column 0 = left (+X)
    if a1 == b"X":  # columns stored as major axis: transpose to rows first
        img = img.transpose(1, 0, 2)
        sy, sx = s2, s1
    else:
        sy, sx = s1, s2
    if sy == b"+":
        img = img[::-1]
    if sx == b"-":
        img = img[:, ::-1]
    return np.ascontiguousarray(img)


def _decode_scanlines(data: bytes, pos: int, n_lines: int, width: int, path) -> np.ndarray:
    """Decode ``n_lines`` scanlines of ``width`` RGBE pixels from ``data[pos:]``:
    new-style RLE, flat, or old-style (``1 1 1 n`` repeat) scanlines, as
    Radiance's ``freadcolrs`` accepts them. Packet headers are walked in plain
    Python; the bytes are expanded with NumPy."""
    out = np.empty((n_lines, width, 4), dtype=np.uint8)
    buf = np.frombuffer(data, dtype=np.uint8)
    size = len(data)
    for row in range(n_lines):
        if (8 <= width <= 0x7FFF and pos + 4 <= size and data[pos] == 2 and data[pos + 1] == 2
                and not data[pos + 2] & 0x80):
            if (data[pos + 2] << 8) | data[pos + 3] != width:
                raise ValueError(f"{path}: corrupt RLE scanline {row} (length "
                                 f"{(data[pos + 2] << 8) | data[pos + 3]}, expected {width})")
            pos += 4
            for ch in range(4):
                src, dst_len, is_run = [], [], []
                filled = 0
                while filled < width:
                    if pos >= size:
                        raise ValueError(f"{path}: truncated file (in scanline {row} of {n_lines})")
                    count = data[pos]
                    if count > 128:
                        count -= 128
                        src.append(pos + 1)
                        is_run.append(True)
                        pos += 2
                    else:
                        if count == 0:
                            raise ValueError(f"{path}: corrupt RLE scanline {row} (zero-length packet)")
                        src.append(pos + 1)
                        is_run.append(False)
                        pos += 1 + count
                    dst_len.append(count)
                    filled += count
                if filled != width or pos > size:
                    raise ValueError(f"{path}: corrupt RLE scanline {row} (packets overrun the "
                                     f"width {width})" if filled != width else
                                     f"{path}: truncated file (in scanline {row} of {n_lines})")
                src_a = np.asarray(src, dtype=np.int64)
                len_a = np.asarray(dst_len, dtype=np.int64)
                run_a = np.asarray(is_run, dtype=bool)
                step = np.repeat(~run_a, len_a).astype(np.int64)
                k = np.arange(width) - np.repeat(np.cumsum(len_a) - len_a, len_a)
                out[row, :, ch] = buf[np.repeat(src_a, len_a) + k * step]
        else:
            # flat pixels, possibly with old-style repeats (1, 1, 1, n: repeat
            # the previous pixel n << shift times, shift growing by 8 per run)
            raw = buf[pos:pos + 4 * width]
            chunk = raw.reshape(-1, 4) if raw.size == 4 * width else None
            if chunk is not None and not np.any((chunk[:, 0] == 1) & (chunk[:, 1] == 1) & (chunk[:, 2] == 1)):
                out[row] = chunk  # the common case: a plain flat scanline
                pos += 4 * width
                continue
            col, shift = 0, 0
            while col < width:
                if pos + 4 > size:
                    raise ValueError(f"{path}: truncated file (in scanline {row} of {n_lines})")
                r, g, b, e = data[pos:pos + 4]
                pos += 4
                if r == 1 and g == 1 and b == 1:
                    if col == 0:
                        raise ValueError(f"{path}: corrupt scanline {row} (repeat before any pixel)")
                    count = e << shift
                    if col + count > width:
                        raise ValueError(f"{path}: corrupt scanline {row} (run past the width)")
                    out[row, col:col + count] = out[row, col - 1]
                    col += count
                    shift += 8
                else:
                    out[row, col] = (r, g, b, e)
                    col += 1
                    shift = 0
    return out


# --------------------------------------------------------------------------
# OpenEXR, PNG, NPY
# --------------------------------------------------------------------------

def _openexr():
    """The OpenEXR module, or an ImportError that says how to install it."""
    try:
        import OpenEXR
    except ImportError as exc:
        raise ModuleNotFoundError(
            ".exr files need the OpenEXR package: pip install 'mcvar[exr]' (or pip install OpenEXR)"
        ) from exc
    return OpenEXR


def _write_exr(path: pathlib.Path, image: np.ndarray) -> None:
    OpenEXR = _openexr()

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": np.ascontiguousarray(image, dtype=np.float32)}) as fh:
        fh.write(str(path))


def _read_exr(path: pathlib.Path) -> np.ndarray:
    OpenEXR = _openexr()

    try:
        with OpenEXR.File(str(path), separate_channels=True) as fh:
            channels = {name: np.asarray(ch.pixels) for name, ch in fh.channels().items()}
    except Exception as exc:  # the binding raises RuntimeError for any bad file
        raise ValueError(f"{path}: not a readable OpenEXR file ({exc})") from exc
    if all(c in channels for c in "RGB"):
        planes = [channels[c] for c in "RGB"]
    elif "Y" in channels:
        planes = [channels["Y"]] * 3
    else:
        raise ValueError(f"{path}: OpenEXR file has no R, G, B (or Y) channels; "
                         f"found {sorted(channels)}")
    return np.stack(planes, axis=-1).astype(np.float64)


def _write_png(path: pathlib.Path, image: np.ndarray, exposure: float) -> None:
    import imageio.v3 as iio

    iio.imwrite(path, to_srgb8(image, exposure=exposure), plugin="pillow", extension=".png")


def _read_png(path: pathlib.Path) -> np.ndarray:
    import imageio.v3 as iio

    try:
        arr = iio.imread(path, plugin="pillow", extension=".png")
    except Exception as exc:
        raise ValueError(f"{path}: not a readable PNG file ({exc})") from exc
    if arr.dtype == np.uint16:
        arr = arr.astype(np.float64) / 65535.0
    elif arr.dtype != np.uint8:
        raise ValueError(f"{path}: unsupported PNG sample type {arr.dtype}")
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=-1)
    elif arr.ndim == 3 and arr.shape[-1] in (2, 4):  # grey+alpha, RGBA: drop alpha
        arr = arr[..., :-1]
        if arr.shape[-1] == 1:
            arr = np.repeat(arr, 3, axis=-1)
    return srgb_to_linear(arr)


def _read_npy(path: pathlib.Path) -> np.ndarray:
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise ValueError(f"{path}: not a readable .npy array ({exc})") from exc
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "fiu":
        raise ValueError(f"{path}: .npy image must hold a numeric array; got {getattr(arr, 'dtype', type(arr))}")
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise ValueError(f"{path}: .npy image must have shape (H, W, 3); got {arr.shape}")
    return arr.astype(np.float64)


# --------------------------------------------------------------------------
# public entry points
# --------------------------------------------------------------------------

def _suffix(path) -> tuple[pathlib.Path, str]:
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a str or os.PathLike; got {type(path).__name__}")
    path = pathlib.Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"path must end in one of {SUFFIXES}; got {path.name!r}")
    return path, suffix


def _check_image(image, name: str) -> np.ndarray:
    img = as_array(image, name, ndim=3, last=3, finite=False)
    if img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"{name} must have shape (H, W, 3) with H, W >= 1; got {img.shape}")
    if not np.all(np.isfinite(img)):
        bad = np.argwhere(~np.isfinite(img))[0]
        raise ValueError(f"{name} must be finite (no NaN or Inf); got {img[tuple(bad)]} at "
                         f"(row, column, channel) = {tuple(int(i) for i in bad)}")
    return img


def write_image(path, image, *, exposure: float = 1.0) -> pathlib.Path:
    """Write an ``(H, W, 3)`` linear image, the format chosen by suffix.

    Parameters
    ----------
    path : str or os.PathLike
        Ends in ``.npy``, ``.exr``, ``.hdr`` or ``.png`` (any case). The
        directory must exist.
    image : array_like, shape (H, W, 3)
        Linear radiance, row 0 at the top; finite (NaN or Inf is a
        ``ValueError``). ``.hdr`` also requires it to be non-negative.
    exposure : float, optional
        For ``.png`` only: the linear multiplier of :func:`to_srgb8` applied
        before clipping to [0, 1] (``2 ** stops``). Ignored by the linear
        formats, which store radiance as is.

    Returns
    -------
    pathlib.Path
        The path written.

    Notes
    -----
    ``.npy`` and ``.exr`` store float32 (about 7 significant digits);
    ``.hdr`` stores RGBE (each channel within 2^-8 of its pixel's largest
    channel, see :func:`rgbe_encode`); ``.png`` stores a display image
    (clipped, 8-bit sRGB), not radiance.

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> img = np.full((2, 4, 3), 0.5)
    >>> p = write_image(d / "grey.npy", img)
    >>> bool(np.array_equal(read_image(p), img))
    True
    """
    path, suffix = _suffix(path)
    img = _check_image(image, "image")
    exposure = check_positive(exposure, "exposure")
    if suffix == ".npy":
        with open(path, "wb") as fh:  # np.save(path) would append '.npy' to other names
            np.save(fh, img.astype(np.float32), allow_pickle=False)
    elif suffix == ".exr":
        _write_exr(path, img)
    elif suffix == ".hdr":
        _write_hdr(path, img)
    else:
        _write_png(path, img, exposure)
    return path


def read_image(path) -> np.ndarray:
    """Read a linear ``(H, W, 3)`` float64 image, the format chosen by suffix.

    Parameters
    ----------
    path : str or os.PathLike
        Ends in ``.npy``, ``.exr``, ``.hdr`` or ``.png``. ``.png`` is decoded
        from sRGB to linear in [0, 1] (a convenience for textures; it holds no
        radiance above 1).

    Returns
    -------
    ndarray of float64, shape (H, W, 3)
        Row 0 at the top.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    IsADirectoryError
        ``path`` names a directory.
    ValueError
        The file cannot be decoded (truncated, corrupt, another format under
        this suffix, wrong shape), or holds NaN or Inf. The message names the
        file.
    """
    if isinstance(path, (str, os.PathLike)) and pathlib.Path(path).is_dir():
        raise IsADirectoryError(f"path {str(path)!r} is a directory, not an image file: give the "
                                f"path of a file inside it ending in one of {SUFFIXES}")
    path, suffix = _suffix(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such image file: {path}")
    reader = {".npy": _read_npy, ".exr": _read_exr, ".hdr": _read_hdr, ".png": _read_png}[suffix]
    img = reader(path)
    if img.ndim != 3 or img.shape[-1] != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise ValueError(f"{path}: decoded image has shape {img.shape}, not (H, W, 3)")
    if not np.all(np.isfinite(img)):
        raise ValueError(f"{path}: image holds NaN or Inf values")
    return img
