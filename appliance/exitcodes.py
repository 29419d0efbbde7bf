"""Process exit codes of every ``ogiflow`` command and of the service (also in docs/operation.md).

systemd restarts the service on any failure except a configuration error
(``RestartPreventExitStatus=2``): a wrong key does not fix itself, a runtime fault may.
"""

#: Success (for ``ogiflow run``: duration elapsed, SIGTERM or SIGINT, every file finalised).
EXIT_OK = 0
#: The job ran but failed (device error, failed check, runtime fault).
EXIT_FAILURE = 1
#: Bad usage or bad input: unknown option, wrong config key, unreadable or malformed file.
EXIT_USAGE = 2
#: Interrupted by SIGINT before a one-shot command finished.
EXIT_INTERRUPTED = 130
