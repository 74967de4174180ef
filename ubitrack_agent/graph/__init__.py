"""The graph layer: the SRG, template service descriptions, pattern matching, planning, data
flows and their DOT pictures (paper sections 2, 3 and 5.1). Pure functions over networkx
graphs: no zenoh, no processes."""
