"""The fork server's kernel preload (straylight.engine.backends.preload): its tables are built by the
strategies the plan runs (their build_table, as trace() builds them), its walks run that plan, and it
never starts embree (every scene it compiles is on numpy's intersector: the server forks workers, so it
must stay free of threads)."""
from straylight.engine.backends import preload
from straylight.engine.runtime import Runtime
from straylight.engine.strategies.first_vertex import FirstVertex


def test_preload_builds_the_tables_through_the_strategies_and_never_starts_embree(monkeypatch):
    intersectors, tables, states = [], [], []
    scene, build, state = Runtime.scene, FirstVertex.build_table, FirstVertex.batch_state

    def scene_seen(self, spec, intersector=None):
        intersectors.append(intersector)
        return scene(self, spec, intersector)

    def build_seen(self, spec, tools):
        tables.append(build(self, spec, tools))
        return tables[-1]

    def state_seen(self, ctx):
        states.append(ctx.spec.vertex_table)
        return state(self, ctx)

    monkeypatch.setattr(Runtime, "scene", scene_seen)
    monkeypatch.setattr(FirstVertex, "build_table", build_seen)
    monkeypatch.setattr(FirstVertex, "batch_state", state_seen)
    preload.load_kernels()
    assert intersectors and all(i is not None for i in intersectors)
    assert len(tables) == 1 and tables[0] is not None  # one of the three option sets samples first vertices
    assert len(states) == 1 and states[0] is tables[0]  # and its walk runs the strategy with that table
