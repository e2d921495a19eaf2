/*
 * json_get PATH < DOCUMENT — parses the document on stdin with cJSON and
 * prints the value at PATH, for the client's shell tests. PATH is
 * '.'-separated: a key of an object, an index of an array, or "#" for the
 * number of items. Strings print raw, other values as compact JSON; "."
 * alone prints the whole document. Exit 1: no such value; 2: not JSON.
 */
#include <cJSON.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define JSON_GET_MAX ((size_t)64 << 20)

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: json_get PATH < DOCUMENT\n");
        return 2;
    }
    char *text = malloc(JSON_GET_MAX + 1);
    if (!text)
        return 2;
    const size_t n = fread(text, 1, JSON_GET_MAX, stdin);
    text[n] = '\0';
    cJSON *root = cJSON_ParseWithLength(text, n);
    free(text);
    if (!root) {
        fprintf(stderr, "json_get: stdin is not a JSON document\n");
        return 2;
    }
    const cJSON *at = root;
    char path[1024];
    snprintf(path, sizeof path, "%s", argv[1]);
    int count = 0;
    for (char *save = NULL, *part = strcmp(path, ".") ? strtok_r(path, ".", &save) : NULL; part;
         part = strtok_r(NULL, ".", &save)) {
        if (strcmp(part, "#") == 0) {
            count = 1;
            break;
        }
        char *end = NULL;
        const long index = strtol(part, &end, 10);
        at = cJSON_IsArray(at) && end && !*end ? cJSON_GetArrayItem(at, (int)index)
                                               : cJSON_GetObjectItemCaseSensitive(at, part);
        if (!at) {
            fprintf(stderr, "json_get: no value at %s\n", argv[1]);
            cJSON_Delete(root);
            return 1;
        }
    }
    if (count) {
        printf("%d\n", cJSON_GetArraySize(at));
    } else if (cJSON_IsString(at)) {
        printf("%s\n", at->valuestring);
    } else {
        char *out = cJSON_PrintUnformatted(at);
        printf("%s\n", out ? out : "");
        free(out);
    }
    cJSON_Delete(root);
    return 0;
}
