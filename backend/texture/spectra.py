"""What the lattice reading takes from a photo pair, computed once: :class:`Spectra`.

Per photo: its strongest spectral peaks (sub-bin positions, :func:`backend.image.spectrum.spectral_peaks`),
its sharp peakness map (log power above its local background, zero-padded twice:
:func:`backend.image.spectrum.peakness`), its high-passed luminance (for the mean spacing over the
whole photo, :mod:`.spacing`) and, for photos larger than :data:`COARSE_SIZE`, the peaks of the photo
shrunk to that size: at full size the strongest peaks can be the aliased high harmonics of a dense
weave, which line up with a wrong comb; shrunk (a box filter in linear light), those lose their
weight and the fundamentals lead.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.threads import ordered_map
from ..image.spectrum import Peak, highpassed_luminance, peakness, shows_weave, spectral_peaks
from ..image.tone import GAMMA, encode, resize_linear

COARSE_SIZE = 256  # photos above this size are also read shrunk to it


@dataclass
class Spectra:
    size: int
    peaks: list[list[Peak]]
    maps: list[np.ndarray]
    highpassed: list[np.ndarray]
    coarse: list[list[Peak]] | None = None

    @classmethod
    def of(cls, images: list[np.ndarray], workers: int = 1) -> "Spectra":
        """The spectra of ``images``, each photo's on one of up to ``workers`` threads."""
        images = [np.asarray(img, dtype=np.float64) for img in images]
        size = images[0].shape[0]

        def read(image: np.ndarray):
            return (spectral_peaks(image), peakness(image, blur=0.0), highpassed_luminance(image, size / 64),
                    spectral_peaks(_shrunk(image, COARSE_SIZE)) if size > COARSE_SIZE else None)

        peaks, maps, highpassed, coarse = zip(*ordered_map(read, images, workers))
        return cls(size, list(peaks), list(maps), list(highpassed), list(coarse) if size > COARSE_SIZE else None)

    @property
    def all_peaks(self) -> list[Peak]:
        return [p for peaks in self.peaks for p in peaks]

    @property
    def shows_weave(self) -> list[bool]:
        """Per photo, whether its spectrum shows a peak that noise alone would not
        (:func:`backend.image.spectrum.chance_peakness`): a dense weave behind a phone's blur can
        leave one photo (a transmission, mostly) with nothing but noise."""
        return [shows_weave(peaks, self.size) for peaks in self.peaks]

    def of_the_weave(self) -> "Spectra":
        """These spectra without the photos that show no weave (:attr:`shows_weave`), unless none
        shows it: the noise peaks of such a photo pull the sieves, and its noise map, which some
        wrong placement always explains best, would veto the turn the other photo shows."""
        keep = self.shows_weave
        if all(keep) or not any(keep):
            return self
        pick = [k for k, shown in enumerate(keep) if shown]
        return Spectra(self.size, [self.peaks[k] for k in pick], [self.maps[k] for k in pick],
                       [self.highpassed[k] for k in pick],
                       None if self.coarse is None else [self.coarse[k] for k in pick])


def _shrunk(image: np.ndarray, size: int) -> np.ndarray:
    """A display-space image shrunk to ``size`` x ``size`` in linear light (area average)."""
    return encode(resize_linear(np.clip(image, 0.0, None) ** GAMMA, size))
