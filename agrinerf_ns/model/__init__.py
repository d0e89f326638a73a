"""The AgriNeRF model, in Nerfstudio's rooms.

- ``model_config``: the settings (`AgriNeRFSettings`); ``model``: the model and `AgriNeRFModelConfig`, which builds it.
- ``plan``: every on/off decision (heads, terms, event supervision, blur model, low light), made once from the config
  and the dataset's metadata.
- ``field``, ``field_heads``, ``vm_encoding``, ``grid_mapping``, ``box_sampler``: the TensoRF field, its heads, the
  VM volumes, the contraction onto the scene's box, the coarse sampler.
- ``parts``: the parts in one table (``PARTS``), each a ``model_part.ModelPart`` (its renders, loss terms, parameter
  groups, metrics), given the render call and the field (``rig``: what they share), not the model: ``loss_routing``
  (``FieldTerms``: the frames' data terms and the regularisers; ``TERMS``: every loss term, the output it reads and
  the part that computes it; the routed copies; ``losses``: the loss functions), ``blur_term`` (the blur model;
  ``rigid_blur``, ``timed_rays``), ``event_term`` (the event loss and EDI prior; ``event_settings``,
  ``event_pairs``, ``event_crf``, ``edi_prior``, ``event_gate``), ``thermal_view`` (the thermal camera's rays),
  ``fruit_head``. ``grid_schedule`` (upsampling, box fits, occupancy updates) runs in the training callbacks;
  ``old_state`` loads older runs' checkpoints.
- ``eval_metrics``, ``gradients``: held-out metrics; per-term gradient diagnostics.

The data stage (dataparser, dataset, event stream) lives in ``agrinerf_ns.dataparsers`` and imports nothing of this.
"""
