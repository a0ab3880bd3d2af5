"""A controller's certified operating envelope over continuous conditions: search for the boundary between the
conditions it drives safely enough and the ones it does not (`search`), then partition the condition space and
certify each region's η1 against a target τ with a family-wise guarantee (`partition`, `certify`)."""
