import numpy as np
import pytest
import torch

from pipeline import ImageFileError, add_poisson_noise, linear_to_srgb, read_image, \
    srgb_to_linear, write_image
from lenssim_studies.paper import PAPER_SENSOR


def ramp(c=3, h=24, w=32):
    y, x = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    return torch.stack([x, y, (x + y) / 2][:c])[None]


@pytest.mark.parametrize("name,bits,tol", [("a.png", 8, 1 / 255), ("a.png", 16, 1 / 65535),
                                           ("a.tif", 16, 1 / 65535), ("a.jpg", 8, 0.06), ("a.exr", "float", 1e-7)])
def test_round_trip(tmp_path, name, bits, tol):
    img = ramp()
    p = write_image(tmp_path / name, img, bits=bits)
    back, info = read_image(p)
    assert back.shape == img.shape and back.dtype == torch.float32
    assert (back - img).abs().max() <= tol
    assert info.linear == (bits == "float")
    assert not list(tmp_path.glob(".*"))  # no temporary files left


def test_grey_and_alpha(tmp_path):
    grey = ramp(1)
    back, info = read_image(write_image(tmp_path / "g.png", grey, bits=16))
    assert back.shape == (1, 1, 24, 32) and info.channels == 1
    import OpenImageIO as oiio

    rgba = np.random.default_rng(0).random((8, 8, 4)).astype(np.float32)
    out = oiio.ImageOutput.create(str(tmp_path / "rgba.png"))
    out.open(str(tmp_path / "rgba.png"), oiio.ImageSpec(8, 8, 4, "uint8"))
    out.write_image(rgba)
    out.close()
    with pytest.warns(UserWarning, match="alpha channel dropped"):
        back, info = read_image(tmp_path / "rgba.png")
    assert back.shape == (1, 3, 8, 8)


def test_unreadable_files_get_clear_errors(tmp_path):
    with pytest.raises(ImageFileError, match="missing.png"):
        read_image(tmp_path / "missing.png")
    bad = tmp_path / "notes.png"
    bad.write_text("this is not an image")
    with pytest.raises(ImageFileError, match="notes.png"):
        read_image(bad)
    good = write_image(tmp_path / "t.png", ramp(h=64, w=64))
    trunc = tmp_path / "trunc.png"
    trunc.write_bytes(good.read_bytes()[: len(good.read_bytes()) // 2])
    with pytest.raises(ImageFileError, match="trunc.png"):
        read_image(trunc)


def test_writes_never_overwrite_inputs_and_check_shapes(tmp_path):
    src = write_image(tmp_path / "in.png", ramp())
    before = src.read_bytes()
    with pytest.raises(ImageFileError, match="one of the inputs"):
        write_image(src, ramp() * 0.5, inputs=[src])
    assert src.read_bytes() == before
    with pytest.raises(ImageFileError, match=r"shape \(2, 3, 24, 32\)|batch of 2"):
        write_image(tmp_path / "x.png", torch.zeros(2, 3, 24, 32))
    with pytest.raises(ImageFileError, match="bits=12"):
        write_image(tmp_path / "x.png", ramp(), bits=12)


def test_srgb_round_trip_and_reference():
    kornia = pytest.importorskip("kornia")
    x = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    lin = srgb_to_linear(x)
    torch.testing.assert_close(lin, kornia.color.rgb_to_linear_rgb(x), rtol=0, atol=1e-6)
    torch.testing.assert_close(linear_to_srgb(lin), x, rtol=0, atol=1e-6)
    assert float(srgb_to_linear(torch.tensor([0.04045]))) == pytest.approx(0.04045 / 12.92, rel=1e-5)
    assert srgb_to_linear(x.double()).dtype == torch.float64
    import colour.constants as cc

    assert cc.DTYPE_FLOAT_DEFAULT == np.float64  # the global setting is restored


@pytest.mark.parametrize("iso", [25, 100, 400])
def test_poisson_noise_statistics(iso):
    fwc = PAPER_SENSOR.full_well_for_iso(iso)
    level = 0.4
    img = torch.full((1, 1, 256, 256), level, dtype=torch.float64)
    img[..., 0, 0] = 1.0  # the maximum maps to the full well
    noisy = add_poisson_noise(img, fwc, seed=1)[..., 1:, :]
    # mean unchanged; variance of a Poisson count of level * fwc electrons, scaled back
    assert float(noisy.mean()) == pytest.approx(level, rel=3e-3)
    assert float(noisy.var()) == pytest.approx(level / fwc, rel=0.03)
    torch.testing.assert_close(add_poisson_noise(img, fwc, seed=1)[..., 1:, :], noisy)  # reproducible


def _sensor(**kw):
    from lenssim import Sensor

    return Sensor(pixel_pitch_um=1.5625, width_px=64, height_px=64, **kw)


@pytest.mark.parametrize("sensor", [None, PAPER_SENSOR, _sensor(read_noise_e=3.0), _sensor(bit_depth=10),
                                    _sensor(read_noise_e=3.0, bit_depth=12)], ids=["ideal", "paper", "read", "adc", "both"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_expose_is_poisson_then_read_noise_then_the_adc(sensor, dtype):
    """expose works in place on its own float64 buffers (two frames at most, not four); the numbers are those of the
    chain written out (Poisson counts, then Gaussian read noise, then rounding to the ADC's levels, drawn from one
    generator in that order) and its input is left as it was."""
    from pipeline.noise import expose

    fwc = 3200.0
    img = torch.rand(1, 3, 40, 36, generator=torch.Generator().manual_seed(2), dtype=dtype)
    keep = img.clone()
    e = fwc / float(img.amax())
    got = expose(img, e, sensor, fwc, generator=torch.Generator().manual_seed(5))
    g = torch.Generator().manual_seed(5)
    x = torch.poisson(img.double() * e, generator=g)
    if sensor is not None and sensor.read_noise_e > 0:
        x = x + sensor.read_noise_e * torch.randn(x.shape, generator=g, dtype=x.dtype)
    if sensor is not None and sensor.bit_depth is not None:
        levels = 2**sensor.bit_depth - 1
        x = torch.round(x / (fwc / levels)).clamp(0, levels) * (fwc / levels)
    assert got.dtype == dtype and torch.equal(got, (x / e).to(dtype))
    assert torch.equal(img, keep)


def test_noise_errors():
    img = torch.ones(1, 1, 4, 4)
    with pytest.raises(ValueError, match="exactly one of generator= or seed="):
        add_poisson_noise(img, 3200.0)
    with pytest.raises(ValueError, match="iso=200"):
        PAPER_SENSOR.full_well_for_iso(200)
    with pytest.raises(ValueError, match="full_well=0"):
        add_poisson_noise(img, 0, seed=0)
    with pytest.raises(ValueError, match="negative"):
        add_poisson_noise(-img, 10.0, seed=0)


def test_gentle_denoise_removes_noise_and_keeps_edges():
    from pipeline.denoise import gentle_denoise

    g = torch.Generator().manual_seed(0)
    clean = torch.zeros(1, 1, 128, 128, dtype=torch.float64)
    clean[..., :, 64:] = 0.6  # a sharp edge
    clean = clean + 0.2
    noisy = clean + 0.02 * torch.randn(clean.shape, generator=g, dtype=torch.float64)
    den = gentle_denoise(noisy, strength=1.0)
    err = lambda x: float(((x - clean) ** 2).mean())  # noqa: E731
    assert err(den) < 0.5 * err(noisy)
    # the edge stays sharp: the step across columns 63 -> 64 keeps most of its height
    step = float((den[..., 64] - den[..., 63]).mean())
    assert step > 0.8 * 0.6
    with pytest.raises(ValueError, match="strength=0"):
        gentle_denoise(noisy, strength=0)


@pytest.mark.parametrize("name,bits", [("a.png", 8), ("a.png", 16), ("a.exr", "float")])
def test_writes_in_bands_give_the_same_file(tmp_path, name, bits, monkeypatch):
    """write_image hands OpenImageIO a band of rows at a time (its host copy stays a band's size): the file is the
    one a single band writes, byte for byte, including a short last band and values outside [0, 1]."""
    import pipeline.io as io

    img = torch.rand(1, 3, 37, 23, generator=torch.Generator().manual_seed(2)) * 1.4 - 0.2
    monkeypatch.setattr(io, "WRITE_BAND_ROWS", 10 ** 6)
    whole = write_image(tmp_path / ("whole_" + name), img, bits=bits).read_bytes()
    monkeypatch.setattr(io, "WRITE_BAND_ROWS", 8)
    banded = write_image(tmp_path / ("banded_" + name), img, bits=bits).read_bytes()
    assert banded == whole
    back = read_image(tmp_path / ("banded_" + name))
    back = back[0] if isinstance(back, tuple) else back
    want = img if bits == "float" else img.clamp(0, 1)
    torch.testing.assert_close(back.reshape(want.shape), want, atol=1e-6 if bits == "float" else 0.6 / (2 ** bits - 1),
                               rtol=0)


def test_eight_bit_images_decode_through_the_table_to_the_same_bits(tmp_path):
    """An 8-bit image (at most one value per code) is decoded through a table of its values: the same bits as
    colour-science on the whole image; an image with more values, or NaN, goes through colour-science itself."""
    import pipeline.colour_space as cs

    g = torch.Generator().manual_seed(1)
    codes = torch.randint(0, 256, (1, 3, 160, 150), generator=g)  # 72,000 values: over the table's least
    assert codes.numel() >= cs._TABLE_LEAST_VALUES
    calls = []
    real = cs._decoded_by_table
    cs._decoded_by_table = lambda t: calls.append(real(t)) or calls[-1]
    try:
        for x in (codes.float() / 255, codes.float() * (1 / 255)):  # two float32 conversions of the codes
            assert torch.equal(srgb_to_linear(x), cs._apply(x, cs._decode))
            assert calls[-1] is not None  # the table was used
        path = tmp_path / "codes.png"
        write_image(path, codes.float() / 255, bits=8)
        img, _ = read_image(path)  # the reader's own conversion
        assert torch.equal(srgb_to_linear(img), cs._apply(img, cs._decode)) and calls[-1] is not None
        more = codes.float() / 255
        more[0, 0, 0, 0] += 1e-4  # a second value for one code: colour-science decodes it all
        assert torch.equal(srgb_to_linear(more), cs._apply(more, cs._decode)) and calls[-1] is None
        nan = codes.float() / 255
        nan[0, 1, 5, 5] = float("nan")
        out = srgb_to_linear(nan)
        assert calls[-1] is None and torch.isnan(out[0, 1, 5, 5]) and torch.equal(out[0, 0], cs._apply(nan, cs._decode)[0, 0])
    finally:
        cs._decoded_by_table = real


@pytest.mark.parametrize("name", ["codes.png", "codes.jpg", "codes.tif"])
def test_eight_bit_files_are_read_through_the_table_of_their_codes(tmp_path, name):
    """An 8-bit file read with ``table`` is its codes looked up in the table of their values: the same bits as the
    function of the float image, whole or by region, for scanline and tiled files; other formats come back as read."""
    import OpenImageIO as oiio

    import pipeline.colour_space as cs
    from pipeline.io import code_values
    from pipeline.photo import open_photo

    g = torch.Generator().manual_seed(2)
    codes = torch.randint(0, 256, (1, 3, 300, 260), generator=g)
    codes[0, :, 0, :256] = torch.arange(256)  # every code present
    path = tmp_path / name
    if name.endswith(".tif"):  # tiled: the lookup follows the tiles' rows
        out = oiio.ImageOutput.create(str(path))
        spec = oiio.ImageSpec(260, 300, 3, "uint8")
        spec.tile_width = spec.tile_height = 64
        assert out.open(str(path), spec)
        assert out.write_image(np.ascontiguousarray(codes[0].permute(1, 2, 0).numpy().astype(np.uint8))), out.geterror()
        out.close()
    else:
        write_image(path, codes.float() / 255, bits=8)
    decode = lambda v: cs._apply(torch.from_numpy(v), cs._decode).numpy()  # noqa: E731  colour-science itself
    plain, info = read_image(path)
    assert info.file_format == "uint8" and (info.tile_height > 0) == name.endswith(".tif")
    # OpenImageIO's own float of each code: the values a float read of the file gives (the PNG and TIFF are exact)
    if not name.endswith(".jpg"):
        assert torch.equal(plain[0, 0, 0, :256], torch.from_numpy(code_values()))
    via, _ = read_image(path, table=decode)
    assert torch.equal(via, cs._apply(plain, cs._decode))
    box = (37, 251, 19, 203)
    part, _ = read_image(path, box, table=decode)
    assert torch.equal(part, via[..., 37:251, 19:203])
    photo = open_photo(str(path))
    assert torch.equal(photo.tensor, srgb_to_linear(plain)) and photo.peak == float(srgb_to_linear(plain).amax())
    lazy = open_photo(str(path), keep_bytes=0)  # read by region on demand
    assert torch.equal(lazy.region(*box), via[..., 37:251, 19:203]) and lazy.peak == photo.peak
    with pytest.raises(ValueError, match="one per code"):
        read_image(path, table=lambda v: v[:10])
    exr = tmp_path / "lin.exr"  # a float file: returned as read
    write_image(exr, via, bits="float")
    assert torch.equal(read_image(exr, table=decode)[0], read_image(exr)[0])


def test_a_header_is_read_once_while_its_file_stays_the_same(tmp_path, monkeypatch):
    import os

    import pipeline.io as pio

    opened = []
    real = pio._open
    monkeypatch.setattr(pio, "_open", lambda p, w: opened.append(p) or real(p, w))
    path = write_image(tmp_path / "h.png", ramp(h=40, w=50))
    a = pio.image_info(path, "photo")
    b = pio.image_info(path, "photo")
    assert a == b and (a.width, a.height) == (50, 40) and len(opened) == 1
    write_image(path, ramp(h=30, w=50))  # replaced (a new inode, another size): read again
    st = os.stat(path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1))
    assert pio.image_info(path, "photo").height == 30 and len(opened) == 2
    with pytest.raises(ImageFileError, match="gone.png"):  # a missing file is never a cached one
        pio.image_info(tmp_path / "gone.png")
