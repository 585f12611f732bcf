"""The physical world robots drive in (pymunk, the ``physics`` extra): ``World``, its parameters and runners (docs/physics.md)."""
