"""The test session runs under the thread limits every Perch entry point applies (perch_common.threads)."""

from perch_common.threads import limit_threads

limit_threads()
