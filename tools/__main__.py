from capstan.tools.cli import main

raise SystemExit(main())
