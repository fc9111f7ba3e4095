"""Case studies built on the library (the library never imports them).

* `bsjax.examples.demo` — the spoon case study of the thesis (§7.3), run by `bsjax demo`.
* `bsjax.examples.spoon` — its steps: bend the handle, attach the bowl, drop a jelly, spill.
* `bsjax.examples.merge_cases` — the seven merging cases of thesis §6.3.1.
"""

__all__: list[str] = []  # the case studies are modules: bsjax.examples.demo, …
