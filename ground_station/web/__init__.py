"""``balloon-gs web``: the ground station in a browser (docs/usage.md, "The ground station in a browser")."""
