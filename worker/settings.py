"""The one settings object (env prefix VPP_), read once; the CLI, service and workers share it."""

from __future__ import annotations

from functools import lru_cache

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from vpp_core.plan import Limits


class Settings(BaseSettings):
    """Limits and resources; every field can be set as VPP_<NAME> in the environment."""

    model_config = SettingsConfigDict(env_prefix="VPP_", frozen=True)

    max_upload_bytes: int = Field(256 * 2**20, gt=0)
    """Largest mesh file accepted (bytes)."""
    max_faces: int = Field(5_000_000, gt=0)
    """Largest mesh accepted (faces)."""
    max_candidates: int = Field(5_000, gt=0)
    """Most candidate viewpoints in one plan."""
    max_rays: int = Field(20_000_000_000, gt=0)
    """Most rays (candidates × pixels) in one plan."""
    threads: int | None = Field(None, gt=0)
    """Threads for ray tracing and the solver; None = all cores this process may use."""

    def limits(self) -> Limits:
        """The core's view of the limits."""
        return Limits(max_candidates=self.max_candidates, max_rays=self.max_rays)


@lru_cache
def get_settings() -> Settings:
    """The settings, read from the environment once."""
    return Settings()
