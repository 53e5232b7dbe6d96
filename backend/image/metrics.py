"""How well a re-render matches a photo (display-space float RGB arrays in [0, 1], same shape).

- ``flip``: mean LDR FLIP error (NVIDIA's perceptual difference; 0 = identical);
- ``colour_l1``: L1 between 16 x 16 area downsamples (colour and tone);
- ``spectrum_corr``: correlation of the smoothed log power spectra of the high-passed luminance
  (:func:`.spectrum.windowed_highpass` with sigma 16 px: Gaussian blur subtracted, Hann window;
  power blurred by sigma 1.5 bins, central half band, 5 x 5 DC neighbourhood dropped): yarn
  structure regardless of phase and lighting;
- ``texture_gap_db``: mean |dB difference| of the two images' texture power per octave band
  (:func:`band_power`, bands :data:`TEXTURE_BANDS`): 0 where the render holds as much yarn-scale
  contrast as the photo at every scale, 10 where a tenth (or ten times) of it. A smooth or blurred
  render shows here even where its spectrum's shape correlates.

These follow the definitions of the team's checker (``shared/tools/imagemetrics.py``); a test
checks that both give the same numbers.
"""
from __future__ import annotations

import cv2
import flip_evaluator
import numpy as np

from .spectrum import power_spectrum, windowed_highpass

SPECTRUM_HIGHPASS_PX = 16     # sigma of the Gaussian subtracted before the FFT
SPECTRUM_POWER_BLUR = 1.5     # sigma of the blur of the power spectrum, in bins
SPECTRUM_KEEP = 0.5           # the central part of the band that is compared
SPECTRUM_DC_HALF = 2          # the (2 h + 1)^2 bins around DC that are dropped
COLOUR_GRID = 16              # side of the area downsample colour_l1 compares
# Octave bands of yarn-scale texture, cycles per pixel of a METRIC_SIZE image (above 1/4 a photo
# holds mostly noise and compression residue).
TEXTURE_BANDS = (1 / 64, 1 / 32, 1 / 16, 1 / 8, 1 / 4)
METRIC_SIZE = 512             # the size the metrics read (the film's); other sizes scale the bands


def colour_l1(photo: np.ndarray, render: np.ndarray) -> float:
    """Mean |photo - render| of the two images' COLOUR_GRID x COLOUR_GRID area downsamples."""
    size = COLOUR_GRID
    a = cv2.resize(np.asarray(photo, np.float32), (size, size), interpolation=cv2.INTER_AREA)
    b = cv2.resize(np.asarray(render, np.float32), (size, size), interpolation=cv2.INTER_AREA)
    return float(np.abs(a - b).mean())


def _log_spectrum(image: np.ndarray) -> np.ndarray:
    """The log power of the central band of the high-passed luminance's blurred spectrum, DC dropped (NaN)."""
    power = cv2.GaussianBlur(power_spectrum(windowed_highpass(image, SPECTRUM_HIGHPASS_PX)), (0, 0),
                             SPECTRUM_POWER_BLUR)
    h, w = power.shape
    ch, cw = int(h * SPECTRUM_KEEP / 2), int(w * SPECTRUM_KEEP / 2)
    band = power[h // 2 - ch: h // 2 + ch, w // 2 - cw: w // 2 + cw].copy()
    d = SPECTRUM_DC_HALF  # the DC neighbourhood (lighting residue) is dropped, as the checker drops it
    band[ch - d: ch + d + 1, cw - d: cw + d + 1] = np.nan
    return np.log(band + 1e-12)


def spectrum_corr(photo: np.ndarray, render: np.ndarray) -> float:
    """Correlation of the two images' :func:`_log_spectrum` over the bins both hold."""
    a, b = _log_spectrum(photo), _log_spectrum(render)
    valid = np.isfinite(a) & np.isfinite(b)
    return float(np.corrcoef(a[valid], b[valid])[0, 1])


def band_power(image: np.ndarray, other: np.ndarray | None = None) -> np.ndarray:
    """Texture power per octave band: the mean over each band of TEXTURE_BANDS (scaled to the
    image's size) of the power spectrum of the high-passed, Hann-windowed luminance (as
    :func:`_log_spectrum` reads it, unblurred). With ``other`` (an image of the same scene with
    independent noise, e.g. a render with other samples) the cross-power Re(F F_other*) instead:
    the noise of one is uncorrelated with the other's, so its mean is the power without the noise.
    A band past the image's Nyquist corner (an image under 128 px) is NaN."""
    def transform(img: np.ndarray) -> np.ndarray:  # the high-pass scales with the image's size
        return np.fft.fft2(windowed_highpass(img, SPECTRUM_HIGHPASS_PX * img.shape[0] / METRIC_SIZE))

    spectrum = transform(image)
    power = np.abs(spectrum) ** 2 if other is None else (spectrum * np.conj(transform(other))).real
    fy = np.fft.fftfreq(power.shape[0])[:, None]
    fx = np.fft.fftfreq(power.shape[1])[None, :]
    radius = np.hypot(fx, fy) * power.shape[0] / METRIC_SIZE   # cycles per pixel of a METRIC_SIZE image
    bands = [(radius >= lo) & (radius < hi) for lo, hi in zip(TEXTURE_BANDS[:-1], TEXTURE_BANDS[1:])]
    return np.array([power[band].mean() if band.any() else np.nan for band in bands])


def power_db(power: np.ndarray) -> np.ndarray:
    """Band powers in dB (a power of 0 or less, as a cross-power can be, reads as -300 dB)."""
    return 10.0 * np.log10(np.maximum(power, 1e-30))


def texture_gap_db(photo: np.ndarray, render: np.ndarray) -> float:
    """Mean |dB difference| of the render's and the photo's :func:`band_power`, over the bands below
    the images' Nyquist corner (all four from 128 px on)."""
    return float(np.nanmean(np.abs(power_db(band_power(render)) - power_db(band_power(photo)))))


def flip(photo: np.ndarray, render: np.ndarray) -> float:
    """Mean LDR FLIP error of the render against the photo."""
    _, value, _ = flip_evaluator.evaluate(np.asarray(photo, np.float32), np.asarray(render, np.float32), "LDR")
    return float(value)


def compare(photo: np.ndarray, render: np.ndarray) -> dict[str, float]:
    """Every metric for one photo/render pair."""
    if photo.shape != render.shape:
        raise ValueError(f"photo {photo.shape} and render {render.shape} differ in size")
    return {"flip": flip(photo, render), "colour_l1": colour_l1(photo, render),
            "spectrum_corr": spectrum_corr(photo, render), "texture_gap_db": texture_gap_db(photo, render)}
