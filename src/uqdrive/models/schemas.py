"""The built-in posteriors' settings defaults in Hydra's ConfigStore (`<method>_schema`, top-level: no option of
the `model` group) and the network's widths (`arch_schema`): conf/model/<method>.yaml and conf/train.yaml extend
them, listing only what differs."""

from __future__ import annotations

from hydra.core.config_store import ConfigStore

from uqdrive.models.ensemble import EnsemblePosterior
from uqdrive.models.hmc import HMCPosterior
from uqdrive.models.laplace import LaplacePosterior
from uqdrive.models.mcd import MCDPosterior
from uqdrive.models.pilotnet import Architecture
from uqdrive.models.vi import VIPosterior
from uqdrive.schema import defaults

BUILT_IN = (MCDPosterior, VIPosterior, HMCPosterior, EnsemblePosterior, LaplacePosterior)


def register_schemas() -> None:
    store = ConfigStore.instance()
    store.store(name="arch_schema", node=defaults(Architecture))
    for posterior in BUILT_IN:
        store.store(name=f"{posterior.method}_schema", node=defaults(posterior.Settings))
