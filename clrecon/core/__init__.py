"""The frame, the plan and its executor, the device layer: what every method stands on."""
