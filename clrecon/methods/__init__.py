"""The reconstruction methods: box, sweep, layered, splat, and the safeguard that wraps
any of them."""
