import sys

from backend.core.threads import wait_briefly

wait_briefly()  # before anything imports torch: the OpenMP runtimes read it when they load

from .cli.main import main  # noqa: E402

sys.exit(main())
