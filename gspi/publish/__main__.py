import sys

from gspi.publish.docs import main

sys.exit(main())
