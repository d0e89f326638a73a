"""Old home of the AgriNeRF dataset: the ``config.yml`` of runs trained before it moved beside the dataparser
(``agrinerf_ns.dataparsers.agrinerf_dataset``) names this module, so ``ns-viewer``, ``ns-eval`` and ``ns-render`` still
load them."""

from agrinerf_ns.dataparsers.agrinerf_dataset import AgriNeRFDataset, agrinerf_datamanager_config

__all__ = ["AgriNeRFDataset", "agrinerf_datamanager_config"]
