"""Files in and out: images and their EXIF, linear raws, model files; atomic writes.

* :mod:`selfcal.io.images` -- image files (OpenCV, Pillow), EXIF exposure data, atomic and
  all-or-nothing writes (:class:`StagedOutputs`); its names are re-exported here;
* :mod:`selfcal.io.exif` -- EXIF: exposure (time, f-number, ISO) and lens, read and written;
* :mod:`selfcal.io.raw` -- raw files as linear camera RGB (rawpy/LibRaw);
* :mod:`selfcal.io.model_file` -- the versioned JSON envelope every model file is written in.

The lowest floor of the library: nothing here imports another selfcal package but
:mod:`selfcal.errors`.
"""

from __future__ import annotations

from .images import (IMAGE_SUFFIXES, JPEG_SUFFIXES, ExposureInfo, OutputWriteError,
                     StagedOutputs, atomic_output, check_output_path,
                     LensInfo, effective_exposure_times, encode_image, exif_rational,
                     format_exposure_time, read_exposure_info, read_image, read_lens_info,
                     read_image_size, write_bytes_atomic, write_image)

__all__ = ["IMAGE_SUFFIXES", "JPEG_SUFFIXES", "read_image", "read_image_size", "ExposureInfo",
           "effective_exposure_times", "format_exposure_time", "read_exposure_info", "OutputWriteError",
           "check_output_path", "atomic_output", "StagedOutputs", "write_bytes_atomic",
           "encode_image", "write_image", "exif_rational", "LensInfo", "read_lens_info"]
