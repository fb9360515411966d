from alacs_eval.cli import main

raise SystemExit(main())
