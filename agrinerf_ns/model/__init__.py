"""The AgriNeRF model, in Nerfstudio's rooms.

- ``model_config``: the settings (`AgriNeRFModelConfig`); ``model``: the model (set-up, render, losses, metrics).
- ``field``, ``field_heads``, ``vm_encoding``, ``grid_mapping``, ``box_sampler``: the TensoRF field, its heads, the
  VM volumes, the contraction onto the scene's box, the coarse sampler.
- ``grid_schedule``: upsampling, box fits and occupancy updates over training.
- ``loss_routing`` and ``losses``: the data terms, how each reaches the density, the loss functions.
- ``blur_renders``, ``rigid_blur``, ``timed_rays``: the blur model. ``event_supervision``, ``event_pairs``,
  ``event_crf``, ``edi_prior``: the event loss and EvDeblurNeRF's event terms.
- ``eval_metrics``, ``gradients``: held-out metrics; per-term gradient diagnostics.

The data stage (dataparser, dataset, event stream) lives in ``agrinerf_ns.dataparsers`` and imports nothing of this.
"""
