"""Registers simeval's config schemas (simeval.config_schemas) when Hydra scans its `hydra_plugins` namespace, which
it does before composing any config: `hydra.compose` in a test or a notebook finds `<entrypoint>_schema` as the
entrypoints do, without importing simeval first."""

import simeval.config_schemas  # noqa: F401  (registers on import)
