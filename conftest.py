"""The test session runs under the thread limits and memory settings every Perch entry point applies
(perch_common.threads, perch_common.memory)."""

from perch_common.memory import tune_memory
from perch_common.threads import limit_threads

limit_threads()
tune_memory()
