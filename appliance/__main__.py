"""Allow ``python -m appliance`` as an alias of the ``ogiflow`` console script."""

from appliance.cli import main

raise SystemExit(main())
