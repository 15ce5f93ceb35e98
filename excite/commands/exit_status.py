"""The exit statuses of ``excite``, each defined once with what it means to a user.

Every problem with the input or the command line ends a command the same way: one line
``excite: error: MESSAGE`` on stderr and :data:`EXIT_USAGE`. A command raises
:class:`~excite.commands.args.UsageError` (or any :class:`~excite.errors.ExciteError`); an
argument type raises :class:`argparse.ArgumentTypeError`, which the parser turns into the same
line, naming the option (``argument --seed: ...``).
"""

from __future__ import annotations

__all__ = ["EXIT_OK", "EXIT_FAILURE", "EXIT_USAGE", "EXIT_UNIDENTIFIABLE", "EXIT_MISFIT",
           "EXIT_OUT_OF_TIME", "EXIT_ABORTED", "EXIT_WORSE", "EXIT_INTERRUPTED", "MEANINGS",
           "calibration_status"]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_UNIDENTIFIABLE = 3
EXIT_MISFIT = 4
EXIT_OUT_OF_TIME = 5
EXIT_ABORTED = 6
EXIT_WORSE = 7
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report Ctrl-C

#: Each exit status and what it means, in words (the epilog of ``excite --help``).
MEANINGS = {
    EXIT_OK: "success",
    EXIT_FAILURE: "internal error: a bug in excite (EXCITE_DEBUG=1 shows the traceback)",
    EXIT_USAGE: "bad input, bad usage or a missing extra: 'excite: error: ...' on stderr",
    EXIT_UNIDENTIFIABLE: "calibrate: the data cannot determine every parameter (the report "
                         "names the direction)",
    EXIT_MISFIT: "calibrate: the model does not fit the data (the report gives the reason)",
    EXIT_OUT_OF_TIME: "live: the time ran out before the target was reached (the report is "
                      "still printed and written)",
    EXIT_ABORTED: "live: the session was aborted, the robot stopped (a stream silent too "
                  "long, wheels that do not follow the command; one line says why); what "
                  "was recorded is kept",
    EXIT_WORSE: "validate: the calibrated robot dead-reckons worse than the nominal one on "
                "the logs (the verdict line)",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C or SIGTERM); compare, tune and sweep keep "
                      "finished work",
}


def calibration_status(result) -> int:
    """A calibration's exit status (a :class:`~excite.calibration.result.CalibrationResult`):
    EXIT_MISFIT when the model does not fit, else EXIT_OK when every parameter is determined,
    else EXIT_UNIDENTIFIABLE."""
    return (EXIT_MISFIT if not result.fit.ok
            else EXIT_OK if result.identifiable else EXIT_UNIDENTIFIABLE)
