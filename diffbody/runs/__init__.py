"""Long runs that lose nothing: the one batch loop (`map_chunks`), chunk stores kept in a
folder (`ChunkStore`), results streamed to a CSV a chunk at a time, the header that says what
produced a run and the check a resumed run passes (`header_changes`), interrupts turned into
clean stops (`Interrupts`, `Interrupted`), several processes, and the reach batch's files
(`BatchRun`). The reach batch, the population scaling, the cloud batch and the folders of
mocap trials all run through it (docs/design.md, "Families")."""

from ._streaming import Interrupted as Interrupted
