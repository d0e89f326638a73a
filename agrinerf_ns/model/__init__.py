"""The AgriNeRF model, in Nerfstudio's rooms.

- ``model_config``: the settings (`AgriNeRFSettings`); ``model``: the model and `AgriNeRFModelConfig`, which builds it.
- ``plan``: every on/off decision (heads, terms, event supervision, blur model, low light), made once from the config
  and the dataset's metadata.
- ``field``, ``field_heads``, ``vm_encoding``, ``grid_mapping``, ``box_sampler``: the TensoRF field, its heads, the
  VM volumes, the contraction onto the scene's box, the coarse sampler.
- The parts, each given the render call and the field (``rig``: what they share), not the model: ``grid_schedule``
  (upsampling, box fits, occupancy updates), ``blur_term`` (the blur model; ``rigid_blur``, ``timed_rays``),
  ``event_term`` (the event loss and EDI prior; ``event_pairs``, ``event_crf``, ``edi_prior``), ``thermal_view``
  (the thermal camera's rays), ``fruit_head``, and ``loss_routing`` (the data terms and how each reaches the
  density; ``losses``: the loss functions).
- ``eval_metrics``, ``gradients``: held-out metrics; per-term gradient diagnostics.

The data stage (dataparser, dataset, event stream) lives in ``agrinerf_ns.dataparsers`` and imports nothing of this.
"""
