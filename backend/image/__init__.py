"""Photo input, a leaf package (numpy, OpenCV, rawpy and ``core`` only, never torch).

- :mod:`.photos`: ``load_pair`` (and ``load_photo``), the orchestration: crop, exposure, working images;
- :mod:`.decode`, :mod:`.containers`: files to upright RGB pixels; :mod:`.tone`: linear light, the
  renders' encoding and the one luminance; :mod:`.flat_field`; :mod:`.pair_checks`: framing and order;
- :mod:`.spectrum`: the one high-pass, Hann window and power spectrum;
- :mod:`.metrics`: photo vs re-render; :mod:`.camera_blur`: the camera's blur from the noise spectrum;
- :mod:`.png`: writing and reading the project's PNGs; :mod:`.errors`: ``PhotoError``.
"""
