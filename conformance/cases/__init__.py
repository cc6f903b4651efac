"""The conformance cases, one module per section; importing this package registers them."""

from __future__ import annotations

from conformance.cases import (  # noqa: F401  (imported for their registrations)
    access,
    alter,
    alter_queue,
    commands,
    control,
    framing,
    negotiation,
    outputs,
    precedence,
    robot,
    robustness,
    sensor,
    shapes,
    state,
    sync,
)
