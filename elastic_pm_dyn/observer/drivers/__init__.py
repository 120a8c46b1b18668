"""What feeds the observer and keeps its results: the message stream shared by the live node
and ``observe`` (:mod:`.stream`), bag input and output, the event filter over a bag with its
fast path, the pipelined pass, the result rows and the prepared recordings of ``tune``."""
