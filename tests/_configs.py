"""A pipeline config file written from small mappings, for the tests of foreign layouts."""


def write_config(path, geometry, readout, steps):
    """``path`` holding ``geometry:``, ``readout:`` (flow mappings) and ``steps:`` (YAML lines)."""
    def flow(d):
        return "{" + ", ".join(f"{k}: {v}" for k, v in d.items()) + "}"
    path.write_text(f"geometry: {flow(geometry)}\nreadout: {flow(readout)}\n"
                    "steps:\n" + "".join(f"  - {s}\n" for s in steps))
    return path
