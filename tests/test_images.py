"""Tests for mcvar.images: round trips within each format's documented
precision, Ward's RGBE layout checked against hand-built files, sRGB against
the IEC 61966-2-1 formulas, and every error path."""
import numpy as np
import pytest

from mcvar.images import (
    SUFFIXES,
    linear_to_srgb,
    read_image,
    rgbe_decode,
    rgbe_encode,
    srgb_to_linear,
    to_srgb8,
    write_image,
)

SEED = 20240917


def _hdr_image(rng, h, w):
    """A high-dynamic-range test image with long runs (exercising RLE run
    packets), literal stretches, exact zeros and very dark pixels."""
    img = rng.lognormal(0.0, 3.0, size=(h, w, 3))
    img[:, : w // 2] = img[:, :1]
    img[0, 0] = 0.0
    if w > 2:
        img[-1, -1] = (1e-30, 0.0, 5e-31)
    return img


# --------------------------------------------------------------------------
# sRGB
# --------------------------------------------------------------------------

def test_srgb_curve_matches_iec_61966_2_1_definition():
    # IEC 61966-2-1: linear segment below 0.0031308, power 1/2.4 above; the
    # two pieces meet (to 1e-7, the standard's rounding of its constants).
    x = np.array([0.0, 0.0031308, 0.18, 0.5, 1.0])
    expect = [0.0, 12.92 * 0.0031308, 1.055 * 0.18 ** (1 / 2.4) - 0.055,
              1.055 * 0.5 ** (1 / 2.4) - 0.055, 1.0]
    np.testing.assert_allclose(linear_to_srgb(x), expect, rtol=1e-15, atol=1e-15)
    lo = 12.92 * 0.0031308
    hi = 1.055 * 0.0031308 ** (1 / 2.4) - 0.055
    assert abs(lo - hi) < 1e-7


def test_srgb_round_trip_and_uint8_decoding():
    x = np.linspace(0.0, 1.0, 1001)
    np.testing.assert_allclose(srgb_to_linear(linear_to_srgb(x)), x, atol=1e-12)
    codes = np.arange(256, dtype=np.uint8)
    np.testing.assert_allclose(srgb_to_linear(codes), srgb_to_linear(codes / 255.0), rtol=0, atol=0)
    assert srgb_to_linear(np.uint8(255)) == 1.0


def test_to_srgb8_clips_and_applies_exposure():
    img = np.array([[[-1.0, 0.0, 0.18], [0.5, 1.0, 7.0]]])
    out = to_srgb8(img)
    assert out.dtype == np.uint8 and out.shape == (1, 2, 3)
    assert out[0, 0, 0] == 0 and out[0, 0, 1] == 0
    assert out[0, 1, 1] == 255 and out[0, 1, 2] == 255
    # exposure is a linear multiplier before the clip: 0.18 * 2 == 0.36
    np.testing.assert_array_equal(to_srgb8(img, exposure=2.0)[0, 0, 2], to_srgb8(np.full((1, 1, 3), 0.36))[0, 0, 0])
    # rounding happens in sRGB code space: x lies within half a code of the
    # decoded value, i.e. between the linear values of code -+ 0.5
    x = np.linspace(0, 1, 500).reshape(1, -1, 1).repeat(3, axis=2)
    code = to_srgb8(x).astype(np.float64)
    lo = srgb_to_linear(np.clip((code - 0.5) / 255.0, 0, 1))
    hi = srgb_to_linear(np.clip((code + 0.5) / 255.0, 0, 1))
    assert np.all((lo <= x + 1e-15) & (x <= hi + 1e-15))


def test_srgb_bad_input():
    with pytest.raises(ValueError, match=r"values must lie in \[0, 1\]"):
        srgb_to_linear(np.array([1.5]))
    with pytest.raises(ValueError, match="exposure must be finite and > 0"):
        to_srgb8(np.zeros((1, 1, 3)), exposure=0.0)
    with pytest.raises(ValueError, match="image must be finite"):
        to_srgb8(np.full((1, 1, 3), np.nan))


# --------------------------------------------------------------------------
# RGBE pixels
# --------------------------------------------------------------------------

def test_rgbe_known_pixels_from_wards_definition():
    # Ward, Graphics Gems II (1991): 1.0 = 0.5 * 2^1 -> mantissa byte 128, E = 129;
    # decoded at the cell centre (128 + 0.5) / 256 * 2^1.
    rgbe = rgbe_encode(np.array([1.0, 0.5, 0.0]))
    np.testing.assert_array_equal(rgbe, [128, 64, 0, 129])
    np.testing.assert_allclose(rgbe_decode(rgbe), [128.5 / 128, 64.5 / 128, 0.5 / 128], rtol=0, atol=0)
    np.testing.assert_array_equal(rgbe_encode(np.zeros(3)), [0, 0, 0, 0])
    np.testing.assert_array_equal(rgbe_decode(np.zeros(4, np.uint8)), [0, 0, 0])
    # below 2^-128 the exponent cannot be stored: black
    np.testing.assert_array_equal(rgbe_encode(np.array([2.0 ** -129, 0, 0])), [0, 0, 0, 0])


def test_rgbe_relative_precision_bound():
    # Each channel comes back within 2^-8 of its pixel's largest channel
    # (half a mantissa step of 2^(e-8), with the largest channel >= 2^(e-1)).
    rng = np.random.default_rng(SEED)
    x = rng.lognormal(0, 20, size=(100_000, 3)) * (rng.random((100_000, 3)) < 0.9)
    x = x[x.max(axis=1) > 2.0 ** -127]
    back = rgbe_decode(rgbe_encode(x))
    m = x.max(axis=1, keepdims=True)
    assert np.all(np.abs(back - x) <= 2.0 ** -8 * m)


def test_rgbe_range_errors():
    with pytest.raises(ValueError, match="non-negative"):
        rgbe_encode(np.array([-1.0, 0, 0]))
    with pytest.raises(ValueError, match="< 2\\^127"):
        rgbe_encode(np.array([2.0 ** 128, 0, 0]))
    with pytest.raises(ValueError, match=r"uint8 array of shape \(\.\.\., 4\)"):
        rgbe_decode(np.zeros((2, 3), np.uint8))


# --------------------------------------------------------------------------
# .hdr files
# --------------------------------------------------------------------------

@pytest.mark.parametrize("shape", [(1, 1), (1, 2), (3, 7), (5, 8), (4, 300), (2, 33000)])
def test_hdr_round_trip_within_rgbe_precision(tmp_path, shape):
    # widths < 8 or > 32767 are stored flat, 8..32767 run-length encoded
    img = _hdr_image(np.random.default_rng(SEED), *shape)
    back = read_image(write_image(tmp_path / "a.hdr", img))
    assert back.shape == img.shape and back.dtype == np.float64
    m = img.max(axis=-1, keepdims=True)
    assert np.all(np.abs(back - img) <= 2.0 ** -8 * m)


def test_hdr_rle_writes_wards_run_packets(tmp_path):
    img = np.ones((16, 1024, 3))  # RGBE (128, 128, 128, 129) everywhere
    data = write_image(tmp_path / "flat.hdr", img).read_bytes()
    # a constant channel of 1024 is 8 runs of 127 and one of 8: 128 + n, value
    channel = bytes([128 + 127, 128]) * 8 + bytes([128 + 8, 128])
    e_channel = bytes([128 + 127, 129]) * 8 + bytes([128 + 8, 129])
    scanline = bytes([2, 2, 1024 >> 8, 1024 & 255]) + channel * 3 + e_channel
    assert data.endswith(b"-Y 16 +X 1024\n" + scanline * 16)
    np.testing.assert_array_equal(read_image(tmp_path / "flat.hdr"), rgbe_decode(rgbe_encode(img)))


def _handmade_hdr(resolution: bytes, body: bytes, fmt=b"FORMAT=32-bit_rle_rgbe\n") -> bytes:
    return b"#?RADIANCE\n" + fmt + b"EXPOSURE=1\n\n" + resolution + b"\n" + body


def test_hdr_reads_handmade_rle_scanline(tmp_path):
    # Ward's new-style RLE, built byte by byte: width 8, one scanline; R is a
    # run of 8 x 128, G literal 8 values, B run 5 + literal 3, E run of 129.
    w = 8
    g = bytes(range(10, 18))
    body = bytes([2, 2, 0, w]) + bytes([128 + 8, 128]) + bytes([8]) + g \
        + bytes([128 + 5, 64, 3, 0, 1, 2]) + bytes([128 + 8, 129])
    path = tmp_path / "hand.hdr"
    path.write_bytes(_handmade_hdr(b"-Y 1 +X 8", body))
    img = read_image(path)
    expect = np.stack([np.full(w, 128), np.arange(10, 18), [64] * 5 + [0, 1, 2], np.full(w, 129)], axis=-1)
    np.testing.assert_array_equal(img[0], rgbe_decode(expect.astype(np.uint8)))


def test_hdr_reads_flat_and_old_style_runs(tmp_path):
    # flat pixels, and Radiance's old RLE: (1, 1, 1, n) repeats the previous pixel n times
    px = [bytes([100, 50, 25, 130]), bytes([1, 1, 1, 3]), bytes([20, 40, 60, 128])]
    path = tmp_path / "old.hdr"
    path.write_bytes(_handmade_hdr(b"-Y 1 +X 5", b"".join(px)))
    img = read_image(path)
    a = rgbe_decode(np.array([100, 50, 25, 130], np.uint8))
    b = rgbe_decode(np.array([20, 40, 60, 128], np.uint8))
    np.testing.assert_array_equal(img[0], [a, a, a, a, b])


@pytest.mark.parametrize("res", [b"-Y 2 +X 3", b"+Y 2 +X 3", b"-Y 2 -X 3", b"+X 3 -Y 2"])
def test_hdr_orientations(tmp_path, res):
    # the file stores its major axis first; row 0 of the result is the top (-Y)
    stored = np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4) + 130
    stored[..., 3] = 128
    path = tmp_path / "o.hdr"
    major, minor = (2, 3) if res.startswith((b"-Y", b"+Y")) else (3, 2)
    path.write_bytes(_handmade_hdr(res, stored.reshape(major, minor, 4).tobytes()))
    got = read_image(path)
    want = rgbe_decode(stored.reshape(major, minor, 4))
    if res.startswith(b"+X"):
        want = want.transpose(1, 0, 2)
    elif res.startswith(b"+Y"):
        want = want[::-1]
    if b"-X" in res:
        want = want[:, ::-1]
    assert got.shape == (2, 3, 3)
    np.testing.assert_array_equal(got, want)


def test_hdr_corrupt_files_are_value_errors_naming_the_file(tmp_path):
    img = _hdr_image(np.random.default_rng(SEED), 6, 40)
    good = write_image(tmp_path / "good.hdr", img).read_bytes()
    cases = {
        "trunc.hdr": (good[: len(good) - 50], "truncated"),
        "nosig.hdr": (b"P6\n" + good[2:], "not a Radiance RGBE file"),
        "nohead.hdr": (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n", "truncated Radiance header"),
        "badres.hdr": (_handmade_hdr(b"-Y two +X 3", b""), "bad Radiance resolution"),
        "xyze.hdr": (_handmade_hdr(b"-Y 1 +X 1", b"\0" * 4, fmt=b"FORMAT=32-bit_rle_xyze\n"), "unsupported Radiance FORMAT"),
        "width.hdr": (_handmade_hdr(b"-Y 1 +X 8", bytes([2, 2, 0, 9]) + b"\x89\x01" * 4), "corrupt RLE scanline 0"),
        "zero.hdr": (_handmade_hdr(b"-Y 1 +X 8", bytes([2, 2, 0, 8, 0])), "zero-length packet"),
        "over.hdr": (_handmade_hdr(b"-Y 1 +X 8", bytes([2, 2, 0, 8, 128 + 9, 1]) + b"\x88\x01" * 3), "overrun"),
        "png.hdr": (b"\x89PNG\r\n\x1a\n" + bytes(100), "not a Radiance RGBE file"),
    }
    for name, (data, message) in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(ValueError, match=message) as info:
            read_image(path)
        assert name in str(info.value)


def test_hdr_refuses_negative_values(tmp_path):
    with pytest.raises(ValueError, match="cannot store negative"):
        write_image(tmp_path / "n.hdr", np.full((1, 2, 3), -0.5))


# --------------------------------------------------------------------------
# .npy, .exr, .png
# --------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", [".npy", ".exr", ".EXR"])
def test_float_formats_round_trip_to_float32(tmp_path, suffix):
    img = _hdr_image(np.random.default_rng(SEED), 5, 9)
    img[2, 3] = (-0.25, 3e5, 1e-20)  # float formats keep negatives and range
    back = read_image(write_image(tmp_path / ("a" + suffix), img))
    assert back.dtype == np.float64 and back.shape == img.shape
    np.testing.assert_array_equal(back, img.astype(np.float32).astype(np.float64))


def test_row_zero_is_the_top_in_every_format(tmp_path):
    img = np.zeros((4, 8, 3))
    img[0, :, 0] = 0.9  # top row red
    img[:, 0, 2] = 0.9  # left column blue
    for suffix in SUFFIXES:
        back = read_image(write_image(tmp_path / f"o{suffix}", img))
        assert np.all(back[0, 1:, 0] > 0.8) and np.all(back[1:, 1:, 0] < 1e-3), suffix
        assert np.all(back[1:, 0, 2] > 0.8) and np.all(back[1:, 1:, 2] < 1e-3), suffix


def test_png_round_trip_is_srgb_quantised(tmp_path):
    rng = np.random.default_rng(SEED)
    img = rng.random((6, 5, 3))
    back = read_image(write_image(tmp_path / "a.png", img))
    np.testing.assert_array_equal(back, srgb_to_linear(to_srgb8(img)))
    # exposure scales before the clip
    back2 = read_image(write_image(tmp_path / "b.png", img, exposure=0.5))
    np.testing.assert_array_equal(back2, srgb_to_linear(to_srgb8(0.5 * img)))


def test_exr_with_luminance_channel_only(tmp_path):
    import OpenEXR

    y = np.arange(6, dtype=np.float32).reshape(2, 3)
    header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"Y": y}) as fh:
        fh.write(str(tmp_path / "y.exr"))
    np.testing.assert_array_equal(read_image(tmp_path / "y.exr"), np.repeat(y[..., None], 3, axis=-1))


def test_npy_wrong_content_and_shape(tmp_path):
    np.save(tmp_path / "flat.npy", np.zeros((4, 5)))
    with pytest.raises(ValueError, match=r"flat\.npy.*shape \(H, W, 3\)"):
        read_image(tmp_path / "flat.npy")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match=r"obj\.npy"):
        read_image(tmp_path / "obj.npy")
    np.save(tmp_path / "nan.npy", np.full((1, 2, 3), np.nan))
    with pytest.raises(ValueError, match=r"nan\.npy: image holds NaN"):
        read_image(tmp_path / "nan.npy")


@pytest.mark.parametrize("suffix", SUFFIXES)
def test_truncated_or_foreign_files_are_value_errors(tmp_path, suffix):
    img = _hdr_image(np.random.default_rng(SEED), 8, 16)
    data = write_image(tmp_path / f"g{suffix}", img).read_bytes()
    trunc = tmp_path / f"t{suffix}"
    trunc.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=f"t\\{suffix}"):
        read_image(trunc)
    foreign = tmp_path / f"f{suffix}"
    foreign.write_bytes(b"this is a text file, not an image\n" * 4)
    with pytest.raises(ValueError, match=f"f\\{suffix}"):
        read_image(foreign)


def test_write_errors(tmp_path):
    with pytest.raises(ValueError, match=r"path must end in one of"):
        write_image(tmp_path / "a.jpg", np.zeros((1, 1, 3)))
    with pytest.raises(TypeError, match="path must be a str or os.PathLike"):
        write_image(3, np.zeros((1, 1, 3)))
    bad = np.zeros((2, 2, 3))
    bad[1, 0, 2] = np.inf
    for suffix in SUFFIXES:
        with pytest.raises(ValueError, match=r"image must be finite.*\(1, 0, 2\)"):
            write_image(tmp_path / f"bad{suffix}", bad)
        assert not (tmp_path / f"bad{suffix}").exists()
    with pytest.raises(ValueError, match=r"image must have 3 dimensions"):
        write_image(tmp_path / "a.npy", np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        write_image(tmp_path / "a.npy", np.zeros((2, 2, 4)))
    with pytest.raises(ValueError, match=r"H, W >= 1"):
        write_image(tmp_path / "a.npy", np.zeros((0, 2, 3)))


def test_missing_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.exr"):
        read_image(tmp_path / "missing.exr")


def test_a_directory_is_named_as_a_directory(tmp_path):
    """Issue 15: a directory used to be reported as 'no such image file'."""
    for d in (tmp_path, tmp_path / "renders.exr"):
        d.mkdir(exist_ok=True)
        with pytest.raises(IsADirectoryError, match="is a directory, not an image file"):
            read_image(d)


def test_npy_header_is_float32_hwc(tmp_path):
    path = write_image(tmp_path / "h.npy", np.ones((3, 4, 3)))
    arr = np.load(path)
    assert arr.dtype == np.float32 and arr.shape == (3, 4, 3)
    assert path.read_bytes().startswith(b"\x93NUMPY")  # an .npy, not a pickle


def test_exr_without_the_openexr_package_says_how_to_install_it(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # import now raises ImportError
    with pytest.raises(ImportError, match=r"mcvar\[exr\]"):
        write_image(tmp_path / "a.exr", np.ones((2, 2, 3)))
