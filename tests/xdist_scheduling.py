"""How the suite's tests are spread over pytest-xdist's workers (a pytest plugin; `conftest.py`
registers it when xdist runs).

A file's tests run on one worker, one after another: the programs a test compiles are still in
that worker's memory for the next test of its file (its fixtures too), where per-test
distribution compiled or loaded them in both (a sample of six files: 7 % less CPU, 6 % less
wall). The notebooks and the documentation's pages share nothing in process (each runs in its
own kernel or process), so they go one by one; the slowest files go first so that both workers
finish together.

xdist's file scheduling (3.8.0) hangs the run when a worker dies (pytest-xdist issues #1323,
#1327, #1378: the dead worker's finished files go back on the queue as empty work, a replacement
worker given a single test waits for a second one forever) and runs the test that killed the
worker again. `ByFile` reports that test failed once, as xdist's per-test scheduling does, and
gives the rest of its file to the surviving workers; `tests/test_scheduling.py` checks it with a
test that kills its worker.
"""

from __future__ import annotations

SLOWEST_FIRST = (
    "tests/test_notebooks.py", "tests/test_doc_blocks.py", "tests/test_optimise.py", "tests/test_collide.py",
    "tests/test_construct.py", "tests/test_mesh_tool.py", "tests/test_mss_scene.py",
    "tests/test_collide_speed.py", "tests/test_mss.py", "tests/test_tool_family.py",
    "tests/test_vsofm.py", "tests/test_sweep.py", "tests/test_basis_banded.py",
)  # fmt: skip
ONE_BY_ONE = ("tests/test_notebooks.py", "tests/test_doc_blocks.py")


def pytest_collection_modifyitems(config, items):
    def rank(item):
        path = item.nodeid.split("::", 1)[0]
        return SLOWEST_FIRST.index(path) if path in SLOWEST_FIRST else len(SLOWEST_FIRST)

    items.sort(key=rank)  # stable: the order within a file, and of the other files, is kept


def pytest_xdist_make_scheduler(config, log):
    """File scope for `-n N` (the default `--dist load`); an explicit other `--dist` is kept."""
    if config.option.dist != "load":
        return None
    from xdist.scheduler import LoadFileScheduling

    class ByFile(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return nodeid if nodeid.startswith(ONE_BY_ONE) else super()._split_scope(nodeid)

        def remove_node(self, node):
            """A worker died: the test it was running is reported failed (returned, not run
            again); the unfinished rest of its files goes back on the queue."""
            workload = self.assigned_work.pop(node)
            pending = [nodeid for unit in workload.values() for nodeid, done in unit.items() if not done]
            if not pending:
                return None
            for unit in workload.values():
                unit.pop(pending[0], None)  # the test it died on
            # only units with a test still to run: a finished one would be sent as empty work
            self.workqueue.update({scope: unit for scope, unit in workload.items() if not all(unit.values())})
            for other in self.assigned_work:
                self._reschedule(other)
            return pending[0]

        def _reschedule(self, node):
            """Top the worker up to more than two pending tests: it runs a test only once it
            holds the next one (or is told to shut down)."""
            while not node.shutting_down:
                if not self.workqueue:
                    node.shutdown()
                    return
                if self._pending_of(self.assigned_work[node]) > 2:
                    return
                self._assign_work_unit(node)

    config.option.loadscopereorder = False  # keep the order above (not by number of tests)
    return ByFile(config, log)
